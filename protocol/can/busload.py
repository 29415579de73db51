"""Worst-case bus load of the cyclic schedule (classic CAN, 11-bit identifiers).

Frame length with worst-case bit stuffing (Davis, Burns, Bril & Lukkien 2007, eq. 1):
``C(n) = 47 + 8 n + floor((34 + 8 n - 1) / 4)`` bits for n data bytes, i.e. 55 bits for an
empty frame (SYNC) and 135 bits for 8 bytes. The schedule per SYNC period is SYNC itself,
every synchronous PDO (a PDO with transmission type N counts 1/N per period) and the
heartbeats of every node and the agent, amortised over the period. EMCY and SDO traffic is
acyclic and not in the budget: the 50 % ceiling leaves the rest for it.
"""
from __future__ import annotations

from dataclasses import dataclass

from protocol.can.devices import DEVICES, HEARTBEAT_PERIOD_MS, Device
from protocol.can.pdo import PdoSpec, cyclic_pdos

BUDGET_PERCENT = 50.0


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

    @property
    def bits_per_cycle(self) -> float:
        return sum(i.bits_per_cycle for i in self.items)

    @property
    def percent(self) -> float:
        return 100.0 * self.bits_per_cycle * self.rate_hz / self.bitrate

    @property
    def within_budget(self) -> bool:
        return self.percent <= BUDGET_PERCENT


def _pdo_item(p: PdoSpec) -> LoadItem:
    return LoadItem(f"{p.device} {p.direction.upper()}{p.number} (0x{p.cob_id:03X})",
                    p.length, 1.0 / p.transmission_type)


def bus_load(rate_hz: float = 200.0, bitrate: int = 1_000_000,
             devices: tuple[Device, ...] = DEVICES) -> BusLoad:
    if not rate_hz > 0 or bitrate <= 0:
        raise ValueError("rate and bitrate must be positive")
    items = [LoadItem("SYNC (0x080)", 0, 1.0)]
    items += [_pdo_item(p) for p in cyclic_pdos(devices)]
    hb_per_cycle = 1000.0 / HEARTBEAT_PERIOD_MS / rate_hz
    items.append(LoadItem("heartbeat agent", 1, hb_per_cycle))
    items += [LoadItem(f"heartbeat {d.name}", 1, hb_per_cycle) for d in devices]
    return BusLoad(rate_hz, bitrate, tuple(items))


def format_report(load: BusLoad) -> str:
    lines = [f"{'frame':<40} {'bytes':>5} {'per cycle':>9} {'bits/cycle':>10}"]
    for item in load.items:
        lines.append(f"{item.name:<40} {item.data_bytes:>5} {item.per_cycle:>9.3f} "
                     f"{item.bits_per_cycle:>10.1f}")
    lines.append(f"{'total':<40} {'':>5} {sum(i.per_cycle for i in load.items):>9.3f} "
                 f"{load.bits_per_cycle:>10.1f}")
    lines.append(f"bus load: {load.percent:.1f}% at {load.bitrate} bit/s, {load.rate_hz:g} Hz")
    return "\n".join(lines)
