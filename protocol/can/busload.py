"""Worst-case bus load of the cyclic schedule (classic CAN, 11-bit identifiers).

Frame length with worst-case bit stuffing (Davis, Burns, Bril & Lukkien 2007, eq. 1):
``C(n) = 47 + 8 n + floor((34 + 8 n - 1) / 4)`` bits for n data bytes, i.e. 55 bits for an
empty frame (SYNC) and 135 bits for 8 bytes. The schedule per SYNC period is SYNC itself,
every synchronous PDO (a PDO with transmission type N counts 1/N per period), every
event-driven TPDO at its event timer (a CiA 402 drive's statusword and mode, 0x1800:5) and the
heartbeats of every node and the agent, both amortised over the period. EMCY and SDO traffic is
acyclic and not in the budget: the ceiling (50 % unless the robot description says otherwise)
leaves the rest for it. Rate, bit rate, heartbeat period and nodes are the description's.
"""
from __future__ import annotations

from dataclasses import dataclass

from protocol.can.pdo import PdoSpec, cyclic_pdos, timed_pdos
from protocol.robot import Device, RobotDescription, default_description

BUDGET_PERCENT = default_description().bus.load_budget_percent
"""The default robot's budget: the cyclic schedule within half the bus."""


def frame_bits(data_bytes: int) -> int:
    """Worst-case length in bits of a standard data frame, stuff bits and 3-bit IFS included."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"classic CAN carries 0..8 data bytes, not {data_bytes}")
    return 47 + 8 * data_bytes + (34 + 8 * data_bytes - 1) // 4


@dataclass(frozen=True)
class LoadItem:
    name: str
    data_bytes: int
    per_cycle: float      # frames per SYNC period

    @property
    def bits_per_cycle(self) -> float:
        return self.per_cycle * frame_bits(self.data_bytes)


@dataclass(frozen=True)
class BusLoad:
    rate_hz: float
    bitrate: int
    items: tuple[LoadItem, ...]
    budget_percent: float = BUDGET_PERCENT

    @property
    def bits_per_cycle(self) -> float:
        return sum(i.bits_per_cycle for i in self.items)

    @property
    def percent(self) -> float:
        return 100.0 * self.bits_per_cycle * self.rate_hz / self.bitrate

    @property
    def within_budget(self) -> bool:
        return self.percent <= self.budget_percent

    @property
    def fits(self) -> bool:
        """The schedule fits on the bus at all (at most 100 %)."""
        return self.percent <= 100.0

    @property
    def min_bitrate(self) -> float:
        """The lowest bit rate [bit/s] that carries this schedule at 100 %."""
        return self.bits_per_cycle * self.rate_hz

    @property
    def max_rate_hz(self) -> float:
        """The highest SYNC rate [Hz] this bit rate carries at 100 % (heartbeats and event timers
        held fixed)."""
        timed = [i.name.startswith("heartbeat") or " every " in i.name for i in self.items]
        per_second = sum(i.bits_per_cycle * self.rate_hz for i, t in zip(self.items, timed) if t)
        per_cycle = sum(i.bits_per_cycle for i, t in zip(self.items, timed) if not t)
        return max(self.bitrate - per_second, 0.0) / per_cycle


def _pdo_item(p: PdoSpec, rate_hz: float) -> LoadItem:
    per_cycle = 1.0 / p.transmission_type if p.synchronous else 1000.0 / p.event_timer_ms / rate_hz
    timer = "" if p.synchronous else f" every {p.event_timer_ms} ms"
    return LoadItem(f"{p.device} {p.direction.upper()}{p.number} (0x{p.cob_id:03X}){timer}", p.length, per_cycle)


def bus_load(rate_hz: float | None = None, bitrate: int | None = None,
             devices: tuple[Device, ...] | None = None, *,
             description: RobotDescription | None = None) -> BusLoad:
    """The schedule's load: of ``description`` (default: the default robot) with its SYNC rate,
    bit rate and nodes unless ``rate_hz``/``bitrate``/``devices`` say otherwise."""
    description = description or default_description()
    rate_hz = description.bus.rate_hz if rate_hz is None else rate_hz
    bitrate = description.bus.bitrate if bitrate is None else bitrate
    devices = description.devices if devices is None else devices
    if not rate_hz > 0 or bitrate <= 0:
        raise ValueError("rate and bitrate must be positive")
    items = [LoadItem("SYNC (0x080)", 0, 1.0)]
    items += [_pdo_item(p, rate_hz) for p in (*cyclic_pdos(devices), *timed_pdos(devices))]
    hb_per_cycle = 1000.0 / description.bus.heartbeat_period_ms / rate_hz
    items.append(LoadItem("heartbeat agent", 1, hb_per_cycle))
    items += [LoadItem(f"heartbeat {d.name}", 1, hb_per_cycle) for d in devices]
    return BusLoad(rate_hz, bitrate, tuple(items), description.bus.load_budget_percent)


def format_report(load: BusLoad) -> str:
    lines = [f"{'frame':<40} {'bytes':>5} {'per cycle':>9} {'bits/cycle':>10}"]
    for item in load.items:
        lines.append(f"{item.name:<40} {item.data_bytes:>5} {item.per_cycle:>9.3f} "
                     f"{item.bits_per_cycle:>10.1f}")
    lines.append(f"{'total':<40} {'':>5} {sum(i.per_cycle for i in load.items):>9.3f} "
                 f"{load.bits_per_cycle:>10.1f}")
    lines.append(f"budget: {load.budget_percent:g}% ({'within' if load.within_budget else 'over'})")
    lines.append(f"bus load: {load.percent:.1f}% at {load.bitrate} bit/s, {load.rate_hz:g} Hz")
    return "\n".join(lines)
