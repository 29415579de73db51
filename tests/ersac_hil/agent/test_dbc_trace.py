"""A CAN trace of a real simulated episode (the agent's recorder, BLF) decoded with cantools and
the generated DBC equals the agent's own telemetry of each cycle within one count."""
from __future__ import annotations

import uuid
from pathlib import Path

import can
import cantools
import pytest

from ersac_hil.agent.bus import AgentBus
from ersac_hil.agent.episode import EpisodeRunner
from ersac_hil.agent.telemetry import JOINTS, STATUS_DEVICES, Telemetry
from ersac_hil.agent.trace import CanRecorder
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.timing import PATIENCE_S, PATIENT, patient_controllers, patient_sdo
from protocol.can import cobid
from protocol.can.busconfig import BusConfig
from protocol.zenoh import EpisodeRequest

pytestmark = pytest.mark.timeout(180)
DBC = Path(__file__).resolve().parents[3] / "protocol" / "can" / "dbc" / "ubot5.dbc"
AXES = {"position": "position_actual", "velocity": "velocity_actual", "current": "motor_current",
        "voltage": "motor_voltage"}
IMU = {"pitch": "pitch", "pitch_rate": "pitch_rate", "pitch_acc": "pitch_acceleration",
       "acc_x": "acceleration_x", "acc_z": "acceleration_z"}


def cycles_of(frames: list[can.Message], db) -> list[dict[str, float]]:
    """Per SYNC of the trace, every TPDO signal that answered it (``<device>.<signal>``). In
    lock-step the next SYNC follows the last TPDO, but the recorder's tap may see a TPDO after
    that SYNC: a frame the previous cycle still lacks is the previous cycle's."""
    tpdos = {m.frame_id: m for m in db.messages if "_TPDO" in m.name}
    out: list[dict[str, float]] = []
    seen: list[set[int]] = []
    for f in frames:
        if f.arbitration_id == cobid.SYNC:
            out.append({})
            seen.append(set())
        elif out and f.arbitration_id in tpdos:
            k = -2 if len(out) > 1 and f.arbitration_id not in seen[-2] and f.arbitration_id not in seen[-1] else -1
            m = tpdos[f.arbitration_id]
            seen[k].add(f.arbitration_id)
            device = m.name.split("_TPDO")[0]
            for name, value in m.decode(f.data, decode_choices=False).items():
                out[k][f"{device}.{name}"] = value
    return out


def expected(tel: Telemetry, db) -> dict[str, tuple[float, float]]:
    """What the trace must show for ``tel``: signal -> (value, one count)."""
    counts = {s.name: s.scale for m in db.messages for s in m.signals}
    device_of = {j: m.name.split("_TPDO")[0] for m in db.messages if "_TPDO" in m.name
                 for s in m.signals for j in JOINTS if s.name.startswith(j + "_")}
    out = {}
    for field, suffix in AXES.items():
        for j, value in zip(JOINTS, getattr(tel, field)):
            name = f"{j}_{suffix}"
            out[f"{device_of[j]}.{name}"] = (value, counts[name])
    for field, name in IMU.items():
        out[f"imu.{name}"] = (getattr(tel, field), counts[name])
    for device, word in zip(STATUS_DEVICES, tel.status):
        out[f"{device}.status_word"] = (word, 1)
    return out


def test_a_recorded_episode_decodes_to_the_agents_telemetry(tmp_path):
    config = BusConfig("virtual", f"dbc-{uuid.uuid4().hex[:8]}")
    robot = SimulatedRobot(config)
    samples: list[Telemetry] = []
    try:
        with AgentBus(config, timing=PATIENT) as bus:
            bus.wait_for_nodes(timeout_s=PATIENCE_S)
            patient_sdo(bus.nodes.values())
            patient_controllers(bus.nodes.values())
            recorder = CanRecorder(config, tmp_path).start()
            try:
                runner = EpisodeRunner(bus, observe=samples.append)
                recorder.begin("ep-dbc")
                result = runner.run(runner.plan(EpisodeRequest("ep-dbc", "bracing", (0.4,), 3)))
                name = recorder.end()
            finally:
                recorder.stop()
    finally:
        robot.close()
    assert result.status == "ok" and len(samples) == round(result.duration_s / 0.005)
    db = cantools.database.load_file(str(DBC))
    cycles = cycles_of(list(can.LogReader(str(tmp_path / name))), db)
    want = [expected(t, db) for t in samples]

    def matches(cycle: dict[str, float], w: dict[str, tuple[float, float]]) -> bool:
        return set(w) <= set(cycle) and all(abs(cycle[k] - v) <= count for k, (v, count) in w.items())

    # the episode's cycles are consecutive SYNCs of the trace (the trace also holds the
    # configuration before them)
    start = next(i for i, c in enumerate(cycles) if matches(c, want[0]))
    assert len(cycles) >= start + len(want)
    bad = [i for i, w in enumerate(want) if not matches(cycles[start + i], w)]
    assert not bad, f"{len(bad)} of {len(want)} cycles differ, first {bad[0]}"
    assert any(abs(v) > 0.01 for v, _ in want[-1].values())  # a robot that moved, not zeros
