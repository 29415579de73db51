"""The commissioning verdict (pure): what was found on the bus against what the description and
its EDS files say.

Defects, one line each (``Defect.line``):

* ``missing node``: a node of the description that does not answer;
* ``extra node``: a node that answers (heartbeat or SDO) and is not in the description;
* ``wrong device type``: 0x1000, or the vendor id / product code of 0x1018, differ from the
  node's EDS;
* ``wrong PDO map``: a PDO's COB-ID, transmission type or mapping read from the node differs
  from its EDS (the agent takes its maps from the EDS, so it would decode garbage);
* ``limit outside the drive's``: a limit of the description that the drive will not give
  (its current limit, position limits, velocity or torque limit is tighter);
* ``wrong encoder resolution``: a CiA 402 drive's increments per motor revolution (0x608F:1 /
  0x608F:2) are not the axis's ``encoder_counts`` (every position, velocity and setpoint the
  agent scales would be off by their ratio).

The simulator's test bench is optional: a real robot has none, so it is never missing.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ersac_hil.commission.scan import Identity, PdoMap
from protocol.robot import RobotDescription

KINDS = ("missing node", "extra node", "wrong device type", "wrong PDO map", "limit outside the drive's",
         "wrong encoder resolution")


@dataclass(frozen=True)
class Defect:
    kind: str
    subject: str
    detail: str

    @property
    def line(self) -> str:
        return f"DEFECT {self.kind}: {self.subject}: {self.detail}"


@dataclass(frozen=True)
class DriveLimits:
    """What one axis's drive allows, in SI units (``None``: not read / the drive has none)."""
    axis: str
    current: float | None = None
    torque: float | None = None
    velocity: float | None = None
    position: tuple[float, float] | None = None
    encoder_counts: float | None = None
    """A CiA 402 drive's encoder increments per motor revolution (0x608F:1 / 0x608F:2)."""
    source: dict[str, str] = field(default_factory=dict)
    """Which object each limit was read from (``{"current": "0x2034:2"}``)."""


@dataclass(frozen=True)
class Expected:
    """One node as the description and its EDS say it should be."""
    name: str
    node_id: int
    identity: Identity
    pdos: tuple[PdoMap, ...]
    optional: bool = False


@dataclass(frozen=True)
class Found:
    """One node as the bus answered (``identity`` None: no SDO answer)."""
    node_id: int
    heard: bool
    identity: Identity | None
    pdos: tuple[PdoMap, ...] = ()


def check_nodes(expected: tuple[Expected, ...], found: dict[int, Found]) -> list[Defect]:
    """Missing, extra, wrong device type and PDO map defects."""
    defects: list[Defect] = []
    by_id = {e.node_id: e for e in expected}
    for e in expected:
        f = found.get(e.node_id)
        subject = f"{e.name} 0x{e.node_id:02X}"
        if f is None or f.identity is None:
            if not e.optional:
                heard = " (its heartbeat is heard but it answers no SDO)" if f is not None and f.heard else ""
                defects.append(Defect("missing node", subject, f"does not answer an SDO read of 0x1000{heard}"))
            continue
        want, got = e.identity, f.identity
        for what, a, b in (("device type 0x1000", want.device_type, got.device_type),
                           ("vendor id 0x1018:1", want.vendor_id, got.vendor_id),
                           ("product code 0x1018:2", want.product_code, got.product_code)):
            if a != b:
                defects.append(Defect("wrong device type", subject,
                                      f"{what} is 0x{b:08X}, its EDS says 0x{a:08X}"))
                break
        else:
            defects += _pdo_defects(subject, e.pdos, f.pdos)
    for node_id, f in sorted(found.items()):
        if node_id not in by_id and (f.heard or f.identity is not None):
            what = (f"answers (device type 0x{f.identity.device_type:08X}, product 0x{f.identity.product_code:X})"
                    if f.identity is not None else "sends heartbeats")
            defects.append(Defect("extra node", f"node 0x{node_id:02X}", f"{what} but is not in the description"))
    return defects


def _pdo_defects(subject: str, want: tuple[PdoMap, ...], got: tuple[PdoMap, ...]) -> list[Defect]:
    have = {(p.direction, p.number): p for p in got}
    out = []
    for p in want:
        name = f"{p.direction.upper()}{p.number}"
        q = have.get((p.direction, p.number))
        if q is None:
            out.append(Defect("wrong PDO map", subject, f"{name} is missing on the node, the EDS has {p.describe()}"))
        elif (p.cob_id, p.transmission_type, p.entries) != (q.cob_id, q.transmission_type, q.entries) and (
                p.enabled or q.enabled):
            out.append(Defect("wrong PDO map", subject, f"{name} is {q.describe()}, the EDS has {p.describe()}"))
    return out


def check_limits(description: RobotDescription, drives: dict[str, DriveLimits]) -> list[Defect]:
    """A description limit beyond what the axis's drive gives; an encoder resolution that is
    not the drive's."""
    defects = []
    for axis in description.axes:
        d = drives.get(axis.name)
        if d is None:
            continue
        src = d.source
        for what, mine, theirs, unit in (("current_limit", axis.current_limit, d.current, "A"),
                                         ("torque_limit", axis.torque_limit, d.torque, "N m"),
                                         ("velocity_limit", axis.velocity_limit, d.velocity, "rad/s")):
            if theirs is not None and mine > theirs * (1 + 1e-9):
                defects.append(Defect("limit outside the drive's", axis.name,
                                      f"{what} {mine:g} {unit} in the description, the drive gives "
                                      f"{theirs:g} {unit} ({src.get(what.split('_')[0], '?')})"))
        if axis.encoder_counts is not None and d.encoder_counts is not None and \
                abs(d.encoder_counts - axis.encoder_counts) > 1e-9 * axis.encoder_counts:
            defects.append(Defect("wrong encoder resolution", axis.name,
                                  f"encoder_counts {axis.encoder_counts} in the description, the drive counts "
                                  f"{d.encoder_counts:g} increments per motor revolution "
                                  f"({src.get('encoder_counts', '?')})"))
        if axis.position_limits is not None and d.position is not None:
            lo, hi = d.position
            if axis.position_limits.min < lo - 1e-9 or axis.position_limits.max > hi + 1e-9:
                defects.append(Defect("limit outside the drive's", axis.name,
                                      f"position_limits [{axis.position_limits.min:g}, {axis.position_limits.max:g}]"
                                      f" rad in the description, the drive stops at [{lo:g}, {hi:g}] rad "
                                      f"({src.get('position', '?')})"))
    return defects
