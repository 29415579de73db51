"""Reading and checking a robot description (TOML, ``protocol.tomlfile.read_toml``).

``load_description(name_or_path)`` takes a shipped description's NAME (``ubot5``, the default,
or ``ubot5-cia402``; files in protocol/robots/) or a path to a ``.toml`` file and returns a
``RobotDescription``, or raises ``DescriptionError`` with one line that names the field
(``axes.elbow_left.gear: must be > 0, got -3``). Unknown keys are refused by name, so a
misspelt field is never silently ignored. Checks against each node's EDS: the file exists and
parses, the objects that hold stiffness and damping exist, and the description's limits lie
inside what the drive's objects accept (their ``LowLimit``/``HighLimit`` times ``Factor``).
The shipped descriptions skip the parse of their EDS files on load (every program that imports
``protocol.can`` loads the default one; the test suite holds them to every check): their EDS
files must still exist.
"""
from __future__ import annotations

import difflib
import functools
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from protocol.robot.eds import object_dictionary_file
from protocol.robot.model import (MODES, PROFILES, Axis, BenchNode, Bus, DescriptionError, ImuNode, Node,
                                  ObjectRef, Range, RobotDescription, eds_path)
from protocol.tomlfile import read_toml

SHIPPED_DIR = Path(__file__).resolve().parents[1] / "robots"
DEFAULT_NAME = "ubot5"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
_REQUIRED = object()

# board objects that carry a per-axis limit the description must respect
_BOARD_CURRENT_LIMIT, _BOARD_VELOCITY_LIMIT = 0x2034, 0x2035


def shipped_names() -> tuple[str, ...]:
    return tuple(sorted(p.stem for p in SHIPPED_DIR.glob("*.toml")))


def load_description(name_or_path: str | Path = DEFAULT_NAME) -> RobotDescription:
    """A shipped description by NAME, or the description in the file at a path.

    Raises:
        DescriptionError: no such name or file, TOML syntax, or a field that is wrong (one line).
    """
    if isinstance(name_or_path, str) and _NAME.fullmatch(name_or_path):
        if name_or_path not in shipped_names():
            raise DescriptionError(f"{name_or_path!r} is no shipped robot description "
                                   f"(shipped: {', '.join(shipped_names())}) and no file")
        return _shipped(name_or_path)
    return _load_file(Path(name_or_path))


def default_description() -> RobotDescription:
    """The uBot-5 on its own motor controller boards (``ubot5``), the paper's robot."""
    return _shipped(DEFAULT_NAME)


@functools.cache
def _shipped(name: str) -> RobotDescription:
    return _load_file(SHIPPED_DIR / f"{name}.toml", name, check_eds=False)


def _load_file(path: Path, label: str | None = None, check_eds: bool = True) -> RobotDescription:
    """The description in ``path``; errors start with ``label`` (default: the path)."""
    data = read_toml(path, DescriptionError)
    try:
        return parse_description(data, base=path.resolve().parent, source=str(path), check_eds=check_eds)
    except DescriptionError as exc:
        raise DescriptionError(f"{label or path}: {exc}") from None


def parse_description(data: dict[str, Any], base: Path | None = None, source: str = "",
                      check_eds: bool = True) -> RobotDescription:
    """A description from its TOML table (what ``tomllib`` gives); ``base`` is the directory
    EDS paths with a directory part are relative to; ``check_eds``: parse each EDS file and
    hold the description to it (else only its existence is checked)."""
    top = _Table(data, "")
    name = top.get("name", _text)
    summary = top.get("summary", _text, "")
    bus = _bus(top.table("bus"))
    node_tables = top.table("nodes")
    nodes = tuple(_node(node_tables.table(key), key, base) for key in node_tables.keys())
    if not nodes:
        raise DescriptionError("nodes: must name at least one drive node")
    axis_tables = top.table("axes")
    by_name = {n.name: n for n in nodes}
    axes = tuple(_axis(axis_tables.table(key), key, by_name) for key in axis_tables.keys())
    if not axes:
        raise DescriptionError("axes: must name at least one axis")
    axis_tables.finish()
    node_tables.finish()
    imu_t = top.table("imu")
    imu = ImuNode(imu_t.get("name", _identifier, "imu"), imu_t.get("node_id", _node_id),
                  _eds(imu_t, base))
    imu_t.finish()
    testbench = None
    if "testbench" in data:
        tb = top.table("testbench")
        testbench = BenchNode(tb.get("name", _identifier, "testbench"), tb.get("node_id", _node_id),
                              _eds(tb, base))
        tb.finish()
    top.finish()
    description = RobotDescription(name, summary, bus, nodes, axes, imu, testbench, source)
    _check_layout(description)
    if check_eds:
        for node in nodes:
            _check_parses(node)
        for axis in axes:
            _check_against_eds(axis)
    return description


# -- tables --------------------------------------------------------------------------------
class _Table:
    """One TOML table being read: remembers its dotted path and which keys were read, so that
    ``finish()`` refuses every key nobody asked for, by name."""

    def __init__(self, data: Any, path: str) -> None:
        if not isinstance(data, dict):
            raise DescriptionError(f"{path}: must be a table, got {_show(data)}")
        self.data, self.path, self._read = data, path, set()

    def where(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def keys(self) -> list[str]:
        return list(self.data)

    def get(self, key: str, check: Callable[[Any, str], Any], default: Any = _REQUIRED) -> Any:
        self._read.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise DescriptionError(f"{self.where(key)}: missing{self._misspelt(key)}")
            return default
        return check(self.data[key], self.where(key))

    def _misspelt(self, key: str) -> str:
        close = difflib.get_close_matches(key, [k for k in self.data if k not in self._read], n=1)
        return f" (is {close[0]!r} a misspelling?)" if close else ""

    def table(self, key: str) -> "_Table":
        self._read.add(key)
        if key not in self.data:
            raise DescriptionError(f"{self.where(key)}: missing{self._misspelt(key)}")
        return _Table(self.data[key], self.where(key))

    def finish(self) -> None:
        unknown = [k for k in self.data if k not in self._read]
        if unknown:
            known = ", ".join(sorted(self._read))
            raise DescriptionError(f"{self.where(unknown[0])}: unknown key (known here: {known})")


def _show(value: Any) -> str:
    if isinstance(value, dict):
        return "a table"
    return repr(value)


def _text(value: Any, where: str) -> str:
    if not isinstance(value, str):
        raise DescriptionError(f"{where}: must be a string, got {_show(value)}")
    return value


def _identifier(value: Any, where: str) -> str:
    if not _NAME.fullmatch(_text(value, where)):
        raise DescriptionError(f"{where}: must be a name of letters, digits, '_' and '-', got {value!r}")
    return value


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DescriptionError(f"{where}: must be a number, got {_show(value)}")
    if not math.isfinite(value):
        raise DescriptionError(f"{where}: must be finite, got {value}")
    return float(value)


def _integer(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise DescriptionError(f"{where}: must be an integer, got {_show(value)}")
    return value


def _positive(value: Any, where: str) -> float:
    number = _number(value, where)
    if not number > 0:
        raise DescriptionError(f"{where}: must be > 0, got {_fmt(number)}")
    return number


def _positive_int(value: Any, where: str) -> int:
    number = _integer(value, where)
    if number <= 0:
        raise DescriptionError(f"{where}: must be > 0, got {number}")
    return number


def _bounded_int(low: int, high: int) -> Callable[[Any, str], int]:
    def check(value: Any, where: str) -> int:
        number = _integer(value, where)
        if not low <= number <= high:
            raise DescriptionError(f"{where}: must be in {low}..{high}, got {number}")
        return number
    return check


_node_id = _bounded_int(1, 127)


def _range(nonnegative: bool = False) -> Callable[[Any, str], Range]:
    def check(value: Any, where: str) -> Range:
        if not isinstance(value, list) or len(value) != 2:
            raise DescriptionError(f"{where}: must be [min, max], got {_show(value)}")
        lo, hi = (_number(v, where) for v in value)
        if not lo < hi:
            raise DescriptionError(f"{where}: min must be < max, got [{_fmt(lo)}, {_fmt(hi)}]")
        if nonnegative and lo < 0:
            raise DescriptionError(f"{where}: must not be negative, got [{_fmt(lo)}, {_fmt(hi)}]")
        return Range(lo, hi)
    return check


_OBJECT = re.compile(r"0x([0-9A-Fa-f]{4}):(\d{1,3})")


def _object_ref(value: Any, where: str) -> ObjectRef:
    match = _OBJECT.fullmatch(_text(value, where))
    if not match or int(match[2]) > 0xFF:
        raise DescriptionError(f"{where}: must be 'INDEX:SUBINDEX' like '0x2012:1', got {value!r}")
    return ObjectRef(int(match[1], 16), int(match[2]))


def _one_of(options: tuple[str, ...]) -> Callable[[Any, str], str]:
    def check(value: Any, where: str) -> str:
        if _text(value, where) not in options:
            raise DescriptionError(f"{where}: must be one of {', '.join(options)}, got {value!r}")
        return value
    return check


def _fmt(x: float) -> str:
    return f"{x:g}"


# -- sections ------------------------------------------------------------------------------
def _bus(t: _Table) -> Bus:
    bitrate = t.get("bitrate", _bounded_int(1, 1_000_000))
    period = t.get("sync_period_ms", _positive)
    agent = t.get("agent_node_id", _node_id)
    heartbeat = t.get("heartbeat_period_ms", _bounded_int(1, 0xFFFF))
    consumer = t.get("consumer_heartbeat_ms", _bounded_int(1, 0xFFFF))
    budget = t.get("load_budget_percent", _positive, 50.0)
    t.finish()
    if budget > 100:
        raise DescriptionError(f"{t.where('load_budget_percent')}: must be <= 100, got {_fmt(budget)}")
    if consumer <= heartbeat:
        raise DescriptionError(f"{t.where('consumer_heartbeat_ms')}: must be > heartbeat_period_ms "
                               f"({heartbeat}), got {consumer}")
    if not period >= 0.1:
        raise DescriptionError(f"{t.where('sync_period_ms')}: must be >= 0.1, got {_fmt(period)}")
    return Bus(bitrate, period, agent, heartbeat, consumer, budget)


def _eds(t: _Table, base: Path | None) -> str:
    name = t.get("eds", _text)
    if "/" in name or "\\" in name:
        path = Path(name)
        name = str(path if path.is_absolute() else (base or Path.cwd()) / path)
    try:
        eds_path(name)
    except FileNotFoundError as exc:
        raise DescriptionError(f"{t.where('eds')}: {exc}") from None
    return name


def _node(t: _Table, name: str, base: Path | None) -> Node:
    _identifier(name, t.path)
    node = Node(name, t.get("node_id", _node_id), t.get("profile", _one_of(PROFILES)), _eds(t, base))
    t.finish()
    return node


def _check_parses(node: Node) -> None:
    try:
        object_dictionary_file(node.eds, node.node_id)
    except Exception as exc:  # canopen raises many kinds on a malformed file
        raise DescriptionError(f"nodes.{node.name}.eds: {node.eds} does not parse as an EDS ({exc})") from None


_IMPEDANCE_MODES = ("impedance", "csp-impedance")


def _axis(t: _Table, name: str, nodes: dict[str, Node]) -> Axis:
    _identifier(name, t.path)
    node_name = t.get("node", _text)
    if node_name not in nodes:
        raise DescriptionError(f"{t.where('node')}: no node {node_name!r} in nodes "
                               f"(nodes: {', '.join(nodes)})")
    node = nodes[node_name]
    mode = t.get("mode", _one_of(MODES[node.profile]))
    gear = t.get("gear", _positive)
    kt = t.get("torque_constant", _positive)
    current = t.get("current_limit", _positive)
    torque = t.get("torque_limit", _positive)
    if torque > kt * gear * current * (1 + 1e-9):
        raise DescriptionError(f"{t.where('torque_limit')}: must be <= torque_constant * gear * "
                               f"current_limit ({_fmt(kt * gear * current)}), got {_fmt(torque)}")
    impedance = mode in _IMPEDANCE_MODES
    need = _REQUIRED if impedance else None
    axis = Axis(
        name=name, node=node.name, node_id=node.node_id,
        subindex=t.get("subindex", _bounded_int(1, 0xFE), 1),
        label=t.get("label", _identifier, name),
        profile=node.profile, eds=node.eds, mode=mode, gear=gear, torque_constant=kt,
        back_emf=t.get("back_emf", _positive, None),
        resistance=t.get("resistance", _positive, None),
        encoder_counts=t.get("encoder_counts", _positive_int,
                             _REQUIRED if node.profile == "cia402" else None),
        position_limits=t.get("position_limits", _range(), None),
        velocity_limit=t.get("velocity_limit", _positive),
        torque_limit=torque, current_limit=current,
        stiffness_range=t.get("stiffness_range", _range(nonnegative=True), need),
        damping_range=t.get("damping_range", _range(nonnegative=True), need),
        stiffness_object=t.get("stiffness_object", _object_ref, need),
        damping_object=t.get("damping_object", _object_ref, need),
    )
    if (axis.stiffness_range is None) != (axis.damping_range is None):
        missing = "damping_range" if axis.damping_range is None else "stiffness_range"
        raise DescriptionError(f"{t.where(missing)}: missing (an impedance needs both ranges)")
    t.finish()
    return axis


def _check_layout(d: RobotDescription) -> None:
    if d.bus.agent_node_id in {n.node_id for n in d.devices}:
        raise DescriptionError(f"bus.agent_node_id: 0x{d.bus.agent_node_id:02X} is also a node's node-id")
    owners: dict[int, str] = {}
    names: set[str] = set()
    sections = [(f"nodes.{n.name}", n.name, n.node_id) for n in d.nodes]
    sections.append(("imu", d.imu.name, d.imu.node_id))
    if d.testbench is not None:
        sections.append(("testbench", d.testbench.name, d.testbench.node_id))
    for where, name, node_id in sections:
        if node_id in owners:
            raise DescriptionError(f"{where}.node_id: 0x{node_id:02X} is already {owners[node_id]}'s")
        if name in names:
            raise DescriptionError(f"{where}: the name {name!r} is taken by another node")
        owners[node_id], names = name, names | {name}
    for n in d.nodes:
        axes = d.node_axes(n.name)
        if not axes:
            raise DescriptionError(f"nodes.{n.name}: no axis is on this node")
        if n.profile == "cia402" and len(axes) > 1:
            raise DescriptionError(f"axes.{axes[1].name}.node: a CiA 402 node carries one axis, "
                                   f"{n.name} already carries {axes[0].name}")
        for number, axis in enumerate(axes, start=1):
            if axis.subindex != number:
                raise DescriptionError(f"axes.{axis.name}.subindex: the axes of node {n.name} must be "
                                       f"numbered 1..{len(axes)}, got {axis.subindex}")
        labels = [a.label for a in axes]
        for axis in axes:
            if labels.count(axis.label) > 1:
                raise DescriptionError(f"axes.{axis.name}.label: {axis.label!r} twice on node {n.name}")


def _drive_range(od, ref: ObjectRef) -> Range | None:  # noqa: ANN001
    """What the drive's object accepts in SI units (None if its EDS gives no limits)."""
    entry = od[ref.index]
    var = entry if ref.subindex == 0 and not hasattr(entry, "subindices") else entry[ref.subindex]
    if var.min is None or var.max is None:
        return None
    factor = float(getattr(var, "factor", 1) or 1)
    return Range(var.min * factor, var.max * factor)


def _has(od, ref: ObjectRef) -> bool:  # noqa: ANN001
    if ref.index not in od:
        return False
    entry = od[ref.index]
    if not hasattr(entry, "subindices"):
        return ref.subindex == 0
    return ref.subindex in entry.subindices


def _check_against_eds(axis: Axis) -> None:
    od = object_dictionary_file(axis.eds, axis.node_id)
    where = f"axes.{axis.name}"
    eds = Path(axis.eds).name
    checks: list[tuple[str, ObjectRef | None, Range | float | None]] = [
        ("stiffness_range", axis.stiffness_object, axis.stiffness_range),
        ("damping_range", axis.damping_object, axis.damping_range)]
    if axis.profile == "ubot-board":
        checks += [("current_limit", ObjectRef(_BOARD_CURRENT_LIMIT, axis.subindex), axis.current_limit),
                   ("velocity_limit", ObjectRef(_BOARD_VELOCITY_LIMIT, axis.subindex), axis.velocity_limit)]
    for field_name, ref, value in checks:
        if ref is None or value is None:
            continue
        object_field = field_name.replace("_range", "_object")
        if not _has(od, ref):
            if field_name.endswith("_range"):
                raise DescriptionError(f"{where}.{object_field}: {ref} is not in {eds}")
            continue  # a board without the object (the wheels have no velocity limit)
        accepted = _drive_range(od, ref)
        if accepted is None:
            continue
        low, high = (value.min, value.max) if isinstance(value, Range) else (value, value)
        if low < accepted.min - 1e-12 or high > accepted.max + 1e-12:
            shown = f"[{_fmt(low)}, {_fmt(high)}]" if isinstance(value, Range) else _fmt(high)
            raise DescriptionError(f"{where}.{field_name}: must lie inside [{_fmt(accepted.min)}, "
                                   f"{_fmt(accepted.max)}] (the drive's {ref} in {eds}), got {shown}")
