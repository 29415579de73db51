"""The robot description (protocol.robot): the shipped files load, the default one gives exactly
the board robot's tables, and every kind of bad description is refused with one line that
names the field."""
import copy
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.can import devices
from protocol.robot import (DescriptionError, Device, Range, default_description, load_description,
                            shipped_names)
from protocol.robot.load import SHIPPED_DIR, parse_description
from protocol.robot.model import SHIPPED_EDS_DIR

UBOT5 = tomllib.loads((SHIPPED_DIR / "ubot5.toml").read_text())
UBOT5_CIA402 = tomllib.loads((SHIPPED_DIR / "ubot5-cia402.toml").read_text())
CIA402_EDS = SHIPPED_EDS_DIR / "cia402_drive.eds"

# the board robot's node table as it was written in code before the description existed
BOARD_TABLE = (
    Device("wheels", 0x10, "wheel.eds", ("left", "right"), ("wheel_left", "wheel_right")),
    Device("torso", 0x11, "torso.eds", ("torso",), ("torso",)),
    Device("arm_left", 0x12, "arm.eds", ("shoulder", "elbow"), ("shoulder_left", "elbow_left")),
    Device("arm_right", 0x13, "arm.eds", ("shoulder", "elbow"), ("shoulder_right", "elbow_right")),
    Device("imu", 0x20, "imu.eds"),
    Device("testbench", 0x7E, "testbench.eds", simulated_only=True),
)


def test_shipped_descriptions():
    assert set(shipped_names()) >= {"ubot5", "ubot5-cia402"}
    assert load_description("ubot5") is default_description()


def test_default_description_is_the_board_robots_table():
    d = default_description()
    assert d.devices == BOARD_TABLE == devices.DEVICES
    assert devices.ROBOT == BOARD_TABLE[:-1]
    assert (devices.AGENT_NODE_ID, devices.HEARTBEAT_PERIOD_MS, devices.CONSUMER_HEARTBEAT_MS) == (1, 100, 250)
    assert (d.bus.bitrate, d.bus.sync_period_s, d.bus.rate_hz) == (1_000_000, 0.005, 200.0)
    assert d.joints == ("wheel_left", "wheel_right", "torso", "shoulder_left", "elbow_left",
                        "shoulder_right", "elbow_right")
    assert devices.device(0x12) is devices.ARM_LEFT and devices.device("imu") is devices.IMU


def test_board_axes_constants():
    d = default_description()
    elbow = d.axis("elbow_left")
    assert (elbow.node, elbow.node_id, elbow.subindex, elbow.label) == ("arm_left", 0x12, 2, "elbow")
    assert (elbow.profile, elbow.mode, elbow.gear, elbow.torque_constant) == ("ubot-board", "impedance", 120.0, 0.0259)
    assert elbow.stiffness_range == Range(0.0, 500.0) and elbow.damping_range == Range(0.0, 50.0)
    assert str(elbow.stiffness_object) == "0x2030:2"
    wheel = d.axis("wheel_right")
    assert wheel.mode == "torque" and not wheel.impedance and wheel.position_limits is None
    assert wheel.torque_limit == pytest.approx(wheel.torque_constant * wheel.gear * wheel.current_limit)


@pytest.mark.skipif(CIA402_EDS.exists(), reason="the CiA 402 drive's EDS is there")
def test_cia402_description_refused_while_its_eds_is_missing():
    with pytest.raises(DescriptionError, match=r"^ubot5-cia402: nodes\.wheel_left\.eds: .*cia402_drive\.eds"):
        load_description("ubot5-cia402")


@pytest.mark.skipif(not CIA402_EDS.exists(), reason="the CiA 402 drive's EDS is not shipped yet")
def test_cia402_description_layout():
    d = load_description("ubot5-cia402")
    ids = {d.name: d.node_id for d in d.devices}
    assert ids == {"imu": 0x20, "wheel_left": 0x21, "wheel_right": 0x22, "torso": 0x23, "shoulder_left": 0x24,
                   "elbow_left": 0x25, "shoulder_right": 0x26, "elbow_right": 0x27, "testbench": 0x7E}
    assert d.joints == default_description().joints
    assert {a.mode for a in d.axes if a.name.startswith("wheel")} == {"cst"}
    assert {a.mode for a in d.axes if not a.name.startswith("wheel")} == {"csp-impedance"}
    assert {(str(a.stiffness_object), str(a.damping_object)) for a in d.axes if a.impedance} == {
        ("0x2012:1", "0x2012:2")}
    assert all(a.eds == "cia402_drive.eds" and a.encoder_counts for a in d.axes)


def _refusal(data: dict) -> str:
    with pytest.raises(DescriptionError) as info:
        parse_description(data)
    message = str(info.value)
    assert "\n" not in message and message
    return message


def _axis_names():
    return st.sampled_from(sorted(UBOT5["axes"]))


POSITIVE = ("gear", "torque_constant", "back_emf", "resistance", "velocity_limit", "current_limit",
            "torque_limit")


@settings(max_examples=60, deadline=None)
@given(axis=_axis_names(), field=st.sampled_from(POSITIVE),
       value=st.one_of(st.floats(max_value=0.0, allow_nan=False, allow_infinity=False), st.integers(max_value=0)))
def test_a_non_positive_constant_is_refused_by_name(axis, field, value):
    data = copy.deepcopy(UBOT5)
    data["axes"][axis][field] = value
    assert _refusal(data).startswith(f"axes.{axis}.{field}: must be > 0, got ")


def _tables(data: dict, path: str = ""):
    for key, value in data.items():
        if isinstance(value, dict):
            where = f"{path}.{key}" if path else key
            if key not in ("nodes", "axes"):
                yield where, value
            yield from _tables(value, where)


TABLES = sorted(where for where, _ in _tables(UBOT5))


def _table(data: dict, where: str) -> dict:
    for part in where.split("."):
        data = data[part]
    return data


@settings(max_examples=60, deadline=None)
@given(where=st.sampled_from([""] + TABLES), key=st.from_regex(r"[a-z][a-z_]{0,12}", fullmatch=True))
def test_an_unknown_key_is_refused_by_name(where, key):
    data = copy.deepcopy(UBOT5)
    table = _table(data, where) if where else data
    if key in table or (not where and key in ("testbench",)):
        return
    table[key] = 1
    prefix = f"{where}.{key}" if where else key
    assert _refusal(data) == _refusal(data) and _refusal(data).startswith(f"{prefix}: ")


REQUIRED = [(w, k) for w in TABLES for k in _table(UBOT5, w)
            if k not in ("name", "label", "subindex", "summary", "load_budget_percent", "back_emf", "resistance")
            and not (w.startswith("axes.") and k in ("position_limits",))
            and not (w in ("imu", "testbench") and k == "name")]


@settings(max_examples=60, deadline=None)
@given(item=st.sampled_from(REQUIRED))
def test_a_missing_field_is_refused_by_name(item):
    where, key = item
    data = copy.deepcopy(UBOT5)
    del _table(data, where)[key]
    assert _refusal(data).startswith(f"{where}.{key}: ")


@settings(max_examples=30, deadline=None)
@given(node=st.sampled_from(sorted(UBOT5["nodes"])), other=st.sampled_from([0x11, 0x12, 0x13, 0x20, 0x7E, 0x10]))
def test_duplicate_node_ids_are_refused(node, other):
    data = copy.deepcopy(UBOT5)
    if UBOT5["nodes"][node]["node_id"] == other:
        return
    data["nodes"][node]["node_id"] = other
    message = _refusal(data)
    assert ".node_id: 0x" in message and "already" in message


@settings(max_examples=30, deadline=None)
@given(node=st.sampled_from(sorted(UBOT5["nodes"])), profile=st.text(min_size=1, max_size=12))
def test_an_unknown_profile_is_refused(node, profile):
    if profile in ("ubot-board", "cia402"):
        return
    data = copy.deepcopy(UBOT5)
    data["nodes"][node]["profile"] = profile
    assert _refusal(data).startswith(f"nodes.{node}.profile: must be one of ubot-board, cia402")


@settings(max_examples=30, deadline=None)
@given(axis=st.sampled_from(["torso", "shoulder_left", "elbow_right"]),
       field=st.sampled_from(["position_limits", "stiffness_range", "damping_range"]),
       low=st.floats(0, 10), drop=st.floats(0, 10))
def test_a_range_with_min_not_below_max_is_refused(axis, field, low, drop):
    data = copy.deepcopy(UBOT5)
    data["axes"][axis][field] = [low, low - drop]
    assert _refusal(data).startswith(f"axes.{axis}.{field}: min must be < max")


@settings(max_examples=30, deadline=None)
@given(axis=st.sampled_from(["torso", "shoulder_left", "elbow_right"]),
       field=st.sampled_from(["stiffness_range", "damping_range"]), excess=st.floats(1e-6, 1e4))
def test_an_impedance_range_beyond_the_drives_is_refused(axis, field, excess):
    data = copy.deepcopy(UBOT5)
    high = {"stiffness_range": 500.0, "damping_range": 50.0}[field]
    data["axes"][axis][field] = [0.0, high + excess]
    message = _refusal(data)
    assert message.startswith(f"axes.{axis}.{field}: must lie inside [0, {high:g}] (the drive's 0x203")


@settings(max_examples=30, deadline=None)
@given(axis=st.sampled_from(["torso", "shoulder_left", "elbow_right"]),
       field=st.sampled_from(["stiffness_range", "damping_range"]), excess=st.floats(1e-6, 1e4))
def test_an_impedance_range_beyond_the_cia402_drives_is_refused(axis, field, excess):
    """0x2012:1/2 of cia402_drive.eds carry their Factor: the range is checked in N m/rad and
    N m s/rad (raw 0..5,000,000 at 1e-3 / 1e-4), not against raw counts."""
    data = copy.deepcopy(UBOT5_CIA402)
    high = {"stiffness_range": 5000.0, "damping_range": 500.0}[field]
    parse_description(data)  # the shipped ranges lie inside
    data["axes"][axis][field] = [0.0, high + excess]
    message = _refusal(data)
    assert message == (f"axes.{axis}.{field}: must lie inside [0, {high:g}] (the drive's "
                       f"0x2012:{1 if field == 'stiffness_range' else 2} in cia402_drive.eds), "
                       f"got [0, {high + excess:g}]")


def test_other_refusals_name_their_field():
    cases = [
        (("nodes", "torso", "eds"), "nope.eds", r"^nodes\.torso\.eds: EDS file nope\.eds"),
        (("axes", "torso", "mode"), "cst", r"^axes\.torso\.mode: must be one of torque, impedance"),
        (("axes", "torso", "node"), "legs", r"^axes\.torso\.node: no node 'legs'"),
        (("axes", "elbow_left", "subindex"), 3, r"^axes\.elbow_left\.subindex: .*numbered 1\.\.2"),
        (("axes", "elbow_left", "gear"), "high", r"^axes\.elbow_left\.gear: must be a number"),
        (("axes", "elbow_left", "torque_limit"), 60.0, r"^axes\.elbow_left\.torque_limit: must be <= "),
        (("axes", "elbow_left", "current_limit"), 31.0, r"^axes\.elbow_left\.current_limit: must lie inside"),
        (("axes", "elbow_left", "stiffness_object"), "0x2030", r"^axes\.elbow_left\.stiffness_object: must be"),
        (("axes", "elbow_left", "stiffness_object"), "0x2099:1", r"^axes\.elbow_left\.stiffness_object: 0x2099:1 is not"),
        (("bus", "agent_node_id"), 0x20, r"^bus\.agent_node_id: 0x20 is also"),
        (("bus", "bitrate"), 2_000_000, r"^bus\.bitrate: must be in 1\.\.1000000"),
        (("bus", "consumer_heartbeat_ms"), 100, r"^bus\.consumer_heartbeat_ms: must be > heartbeat_period_ms"),
        (("imu", "node_id"), 0x80, r"^imu\.node_id: must be in 1\.\.127"),
    ]
    for path, value, pattern in cases:
        data = copy.deepcopy(UBOT5)
        _table(data, ".".join(path[:-1]))[path[-1]] = value
        with pytest.raises(DescriptionError, match=pattern):
            parse_description(data)
    data = copy.deepcopy(UBOT5)
    data["axes"]["elbow_left"]["node"] = "torso"
    data["axes"]["elbow_left"]["subindex"] = 2
    # two axes on the torso board are a layout it could have, but its EDS has one axis's objects
    assert _refusal(data) == "axes.elbow_left.stiffness_object: 0x2030:2 is not in torso.eds"
    data = copy.deepcopy(UBOT5)
    data["axes"]["elbow_left"]["gera"] = data["axes"]["elbow_left"].pop("gear")
    assert _refusal(data) == "axes.elbow_left.gear: missing (is 'gera' a misspelling?)"
    data = copy.deepcopy(UBOT5)
    data["axes"]["torso"]["label"] = "torso"
    data["axes"]["shoulder_left"]["label"] = "elbow"
    assert _refusal(data).startswith("axes.shoulder_left.label: 'elbow' twice on node arm_left")


def test_files_and_names(tmp_path: Path):
    with pytest.raises(DescriptionError, match=r"^'ubot9' is no shipped robot description \(shipped: ubot5"):
        load_description("ubot9")
    with pytest.raises(DescriptionError, match=r"cannot read it"):
        load_description(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(DescriptionError, match=r"bad\.toml: not valid TOML: .*line 1"):
        load_description(bad)
    # a copy next to its own EDS file (a path with a directory part is relative to the TOML)
    (tmp_path / "eds").mkdir()
    (tmp_path / "eds" / "vendor.eds").write_bytes((SHIPPED_EDS_DIR / "torso.eds").read_bytes())
    text = (SHIPPED_DIR / "ubot5.toml").read_text().replace('eds = "torso.eds"', 'eds = "eds/vendor.eds"')
    mine = tmp_path / "mine.toml"
    mine.write_text(text)
    d = load_description(str(mine))
    assert d.device("torso").eds_path == tmp_path / "eds" / "vendor.eds"
    assert d.source == str(mine)


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ersac_hil.cli", *args], capture_output=True, text=True,
                          timeout=120)


def test_bus_load_cli_reads_the_description(tmp_path: Path):
    out = _cli("bus-load", "--description", "ubot5", "--check")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1].startswith("bus load: 40.7% at 1000000 bit/s, 200 Hz")
    bad = tmp_path / "bad.toml"
    bad.write_text((SHIPPED_DIR / "ubot5.toml").read_text().replace("gear = 120.0", "gear = -3", 1))
    out = _cli("bus-load", "--description", str(bad))
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.count("\n") == 1 and "axes.elbow_left.gear: must be > 0, got -3" in out.stderr


def test_bus_load_cli_refuses_a_schedule_the_bus_cannot_carry():
    out = _cli("bus-load", "--bitrate", "125000")
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.count("\n") == 1
    assert "needs 325 % of a 125000 bit/s bus at 200 Hz" in out.stderr and "at least 406550 bit/s" in out.stderr


@pytest.mark.skipif(not CIA402_EDS.exists(), reason="the CiA 402 drive's EDS is not shipped yet")
def test_cia402_schedule_within_seventy_percent():
    out = _cli("bus-load", "--description", "ubot5-cia402", "--check")
    assert out.returncode == 0, out.stdout + out.stderr
    last = out.stdout.strip().splitlines()[-1]
    assert last.endswith("at 1000000 bit/s, 200 Hz") and float(last.split()[2].rstrip("%")) <= 70.0


@pytest.mark.skipif(not CIA402_EDS.exists(), reason="the CiA 402 drive's EDS is not shipped yet")
def test_the_documented_example_loads(tmp_path: Path):
    doc = (Path(__file__).resolve().parents[2] / "docs" / "robot_description.md").read_text()
    example = doc.split("```toml\n", 1)[1].split("```", 1)[0]
    (tmp_path / "eds").mkdir()
    (tmp_path / "eds" / "md80.eds").write_bytes(CIA402_EDS.read_bytes())
    (tmp_path / "one-arm.toml").write_text(example)
    d = load_description(tmp_path / "one-arm.toml")
    assert d.joints == ("shoulder_left", "elbow_left") and d.testbench is None
    assert [a.mode for a in d.axes] == ["csp-impedance", "cst"]


@pytest.mark.parametrize("name", ["ubot5", "ubot5-cia402"])
def test_shipped_descriptions_pass_every_eds_check(name):
    """Shipped descriptions are loaded without parsing their EDS files: held to them here."""
    path = SHIPPED_DIR / f"{name}.toml"
    if name == "ubot5-cia402" and not CIA402_EDS.exists():
        pytest.skip("the CiA 402 drive's EDS is not shipped yet")
    full = parse_description(tomllib.loads(path.read_text()), base=SHIPPED_DIR, source=str(path))
    assert full == load_description(name)


def test_a_malformed_eds_is_refused(tmp_path: Path):
    (tmp_path / "eds").mkdir()
    (tmp_path / "eds" / "broken.eds").write_text("[1000]\nParameterName=Device type\nObjectType=0x7\n")
    text = (SHIPPED_DIR / "ubot5.toml").read_text().replace('eds = "torso.eds"', 'eds = "eds/broken.eds"')
    (tmp_path / "r.toml").write_text(text)
    with pytest.raises(DescriptionError, match=r"r\.toml: nodes\.torso\.eds: .*broken\.eds does not parse"):
        load_description(tmp_path / "r.toml")
