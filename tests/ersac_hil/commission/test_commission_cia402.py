"""``ersac-hil commission`` against the simulated robot on CiA 402 drives (``ubot5-cia402``: one
drive per axis): the right description passes; each defect of a wrong one is one line."""
from __future__ import annotations

import uuid
from pathlib import Path

import pytest

from ersac_hil.cli import main
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.timing import PATIENCE_MS
from protocol.can.busconfig import BusConfig
from protocol.robot import load_description
from protocol.robot.load import SHIPPED_DIR
from protocol.robot.model import SHIPPED_EDS_DIR

pytestmark = pytest.mark.timeout(120)
CIA402 = (SHIPPED_DIR / "ubot5-cia402.toml").read_text()


@pytest.fixture(scope="module")
def robot():
    description = load_description("ubot5-cia402")
    bus = BusConfig("virtual", f"commission402-{uuid.uuid4().hex[:8]}")
    with SimulatedRobot(bus, description=description, devices=description.devices) as sim:
        yield bus, sim


def run(bus: BusConfig, description: str, tmp_path: Path, capsys) -> tuple[int, list[str]]:
    code = main(["commission", "--description", description, "--bus-interface", bus.interface,
                 "--bus-channel", bus.channel, "--commission-record", str(tmp_path / "record.json"),
                 "--sdo-timeout-ms", str(PATIENCE_MS)])
    out = capsys.readouterr()
    return code, [line for line in (out.out + out.err).splitlines() if line.startswith(("DEFECT", "PASS", "axis"))]


def wrong(tmp_path: Path, old: str, new: str) -> str:
    assert old in CIA402
    path = tmp_path / "wrong.toml"
    path.write_text(CIA402.replace(old, new, 1))
    return str(path)


def swap_tpdo1(eds: Path) -> str:
    """The EDS with TPDO1's first two mapping entries swapped."""
    text = eds.read_text()
    at = [text.index("DefaultValue=", text.index(f"[1A00sub{sub}]")) for sub in (1, 2)]
    values = [text[a + len("DefaultValue="):text.index("\n", a)] for a in at]
    for a, new in sorted(zip(at, reversed(values)), reverse=True):
        end = text.index("\n", a)
        text = text[:a] + "DefaultValue=" + new + text[end:]
    return text


def test_the_right_description_passes(robot, tmp_path, capsys):
    code, lines = run(robot[0], "ubot5-cia402", tmp_path, capsys)
    assert code == 0 and lines[-1].startswith("PASS") and sum(line.startswith("axis") for line in lines) == 7
    assert (tmp_path / "record.json").exists()


def test_a_missing_drive(robot, tmp_path, capsys):
    path = wrong(tmp_path, "[nodes.elbow_right]\nnode_id = 0x27", "[nodes.elbow_right]\nnode_id = 0x37")
    code, lines = run(robot[0], path, tmp_path, capsys)
    assert code == 1 and "DEFECT missing node: elbow_right 0x37: does not answer an SDO read of 0x1000" in lines


def test_a_wrong_device_type(robot, tmp_path, capsys):
    path = wrong(tmp_path, 'node_id = 0x20\neds = "imu.eds"', 'node_id = 0x20\neds = "testbench.eds"')
    code, lines = run(robot[0], path, tmp_path, capsys)
    assert code == 1 and [d for d in lines if d.startswith("DEFECT")] == [
        "DEFECT wrong device type: imu 0x20: product code 0x1018:2 is 0x00000004, its EDS says 0x000000F0"]


def test_a_wrong_pdo_map(robot, tmp_path, capsys):
    (tmp_path / "drive.eds").write_text(swap_tpdo1(SHIPPED_EDS_DIR / "cia402_drive.eds"))
    path = wrong(tmp_path, '[nodes.elbow_left]\nnode_id = 0x25\nprofile = "cia402"\neds = "cia402_drive.eds"',
                 f'[nodes.elbow_left]\nnode_id = 0x25\nprofile = "cia402"\neds = "{tmp_path / "drive.eds"}"')
    code, lines = run(robot[0], path, tmp_path, capsys)
    defects = [d for d in lines if d.startswith("DEFECT")]
    assert code == 1 and len(defects) == 1
    assert defects[0].startswith("DEFECT wrong PDO map: elbow_left 0x25: TPDO1 is COB-ID 0x1A5 type 255 "
                                 "[6041:0/16 6061:0/8], the EDS has COB-ID 0x1A5 type 255 [6061:0/8 6041:0/16")


def test_a_limit_outside_the_drives(robot, tmp_path, capsys):
    old = "position_limits = [-0.1, 2.6]\nvelocity_limit = 10.0\ncurrent_limit = 12.0"
    path = wrong(tmp_path, old, old.replace("current_limit = 12.0", "current_limit = 15.0"))
    code, lines = run(robot[0], path, tmp_path, capsys)
    assert code == 1 and [d for d in lines if d.startswith("DEFECT")] == [
        "DEFECT limit outside the drive's: elbow_left: current_limit 15 A in the description, the drive gives "
        "12 A (0x6073 x 0x6075)"]


def test_an_encoder_resolution_that_is_not_the_drives(robot, tmp_path, capsys):
    path = wrong(tmp_path, "encoder_counts = 16384", "encoder_counts = 4096")  # the first axis: wheel_left
    code, lines = run(robot[0], path, tmp_path, capsys)
    assert code == 1 and [d for d in lines if d.startswith("DEFECT")] == [
        "DEFECT wrong encoder resolution: wheel_left: encoder_counts 4096 in the description, the drive "
        "counts 16384 increments per motor revolution (0x608F:1 / 0x608F:2)"]
    assert not (tmp_path / "record.json").exists()
