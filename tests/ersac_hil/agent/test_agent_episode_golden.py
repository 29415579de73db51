"""Episodes are bit-identical across changes of the code that carries them.

Speed work on the hot path (PDO packing, telemetry decoding, the simulator's firmware and
stepping, the CAN transport) must not change a single bit of what an episode measures: the
reproduction figures of docs/reproduce.md were measured on this physics. A few bracing and
lifting episodes (seed + policy) are run through the agent and the simulated robot, and
every cycle's telemetry, the cost terms, failures and the telemetry summary are compared
with ``episode_golden.json``, written by the code the figures were measured on (exact
floats, as hex).

A change that is meant to alter the numerics (new physics, a different controller) rewrites
the file deliberately and says so in its commit::

    .venv/bin/python tests/ersac_hil/agent/test_agent_episode_golden.py   # rewrites the file
"""
from __future__ import annotations

import hashlib
import json
import sys
import uuid
from collections.abc import Mapping
from pathlib import Path

import pytest

from ersac_hil.agent.bus import AgentBus
from ersac_hil.agent.episode import EpisodeRunner
from ersac_hil.agent.telemetry import Telemetry
from firmware_sim.nodes.simrobot import SimulatedRobot
from protocol.can.busconfig import BusConfig
from protocol.zenoh import EpisodeRequest

GOLDEN = Path(__file__).with_name("episode_golden.json")
EPISODES = (  # (task, theta, seed): a fall, a broken cable, a firm brace, a lift, a stalled lift,
    # a dropped bottle
    ("bracing", (0.0,), 0),
    ("bracing", (1.0,), 2),
    ("bracing", (0.35,), 5),
    ("lifting", (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2), 0),
    ("lifting", (0.886, 0.733, 1.771, 0.517, 0.72, 0.72, 0.72), 3),
    ("lifting", (1.2, 1.4, 2.2, 0.9, 0.2, 0.2, 0.2), 605000),
)
_TIMING = ("sync_latency_p50_ms", "sync_latency_p99_ms", "sync_latency_max_ms")
"""Summary entries measured on the wall clock (not part of what an episode measures)."""


def _exact(value: object) -> object:
    """``value`` with every float as its exact hex form (tuples as lists)."""
    if isinstance(value, float):
        return value.hex()
    if isinstance(value, (tuple, list)):
        return [_exact(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _exact(v) for k, v in sorted(value.items())}
    return value


def _telemetry_digest(samples: list[Telemetry]) -> str:
    """sha256 of every cycle's telemetry (exact floats; cycle numbers from the first)."""
    h = hashlib.sha256()
    first = samples[0].cycle if samples else 0
    for s in samples:
        h.update(json.dumps(_exact([s.cycle - first, s.position, s.velocity, s.current, s.voltage,
                                    s.pitch, s.pitch_rate, s.pitch_acc, s.acc_x, s.acc_z,
                                    list(s.status)])).encode())
    return h.hexdigest()


class _RecordingBus(AgentBus):
    """An ``AgentBus`` that keeps the telemetry of every cycle."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.samples: list[Telemetry] = []

    def cycle(self, commands=None) -> Telemetry:  # noqa: ANN001
        tel = super().cycle(commands)
        self.samples.append(tel)
        return tel


def run_episodes(config: BusConfig) -> dict[str, dict]:
    """Every episode of ``EPISODES`` on a simulated robot on ``config``: what it measured."""
    from helpers.timing import PATIENCE_S, PATIENT, patient_controllers, patient_sdo

    out = {}
    with SimulatedRobot(config):
        bus = _RecordingBus(config, timing=PATIENT).open()
        try:
            bus.wait_for_nodes(timeout_s=PATIENCE_S)
            patient_sdo(bus.nodes.values())
            patient_controllers(bus.nodes.values())
            runner = EpisodeRunner(bus)
            for task, theta, seed in EPISODES:
                bus.samples.clear()
                r = runner.run(runner.plan(EpisodeRequest("golden", task, theta, seed)))
                summary = {k: v for k, v in r.telemetry.items() if k not in _TIMING}
                out[f"{task} {theta} seed {seed}"] = _exact({
                    "status": r.status, "cost_terms": r.cost_terms, "total_cost": r.total_cost,
                    "failures": r.failures, "duration_s": r.duration_s, "detail": r.detail,
                    "summary": summary, "telemetry_sha256": _telemetry_digest(bus.samples),
                    "cycles": len(bus.samples)})
        finally:
            bus.close()
    return out


@pytest.mark.timeout(300)
@pytest.mark.parametrize("backend", ["virtual", "zenoh"])
def test_episodes_are_bit_identical_to_the_golden_record(backend, request):
    if backend == "virtual":
        config = BusConfig("virtual", f"golden-{uuid.uuid4().hex[:8]}")
    else:
        router = request.getfixturevalue("can_router")
        config = BusConfig("zenoh", f"golden-{uuid.uuid4().hex[:8]}@{router.endpoint}")
    golden = json.loads(GOLDEN.read_text())
    measured = run_episodes(config)
    assert measured.keys() == golden.keys()
    for name, expected in golden.items():
        assert measured[name] == expected, name


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    GOLDEN.write_text(json.dumps(run_episodes(BusConfig("virtual", f"golden-{uuid.uuid4().hex[:8]}")),
                                 indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN}")
