"""``agent --record-series``: the real agent against the real simulated robot writes each
episode's time series after its reply, and the report draws it (``episode.png``)."""
from __future__ import annotations

import uuid

import matplotlib.pyplot as plt
import numpy as np
import pytest

from ersac_hil.agent.robot import UBOT
from ersac_hil.agent.service import AgentConfig, AgentService
from ersac_hil.daemon.episode_plot import ground_contact_s, plot_episodes, strike_s
from ersac_hil.episode_series import read_series
from ersac_hil.zenoh_session import EmbeddedRouter
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.can_nodes import Master
from helpers.timing import PATIENCE_S, PATIENT, patient_controllers
from helpers.waiting import wait_until
from protocol.can.busconfig import BusConfig
from protocol.can.devices import DEVICES
from protocol.can.objects import EmcyCode
from protocol.zenoh import EpisodeRequest, EpisodeResult, KeySpace

pytestmark = pytest.mark.timeout(180)
ROBOT = "ubot-series"


def test_recorded_series_are_the_episodes_and_the_report_draws_them(tmp_path):
    bus = BusConfig("virtual", f"series-{uuid.uuid4().hex[:8]}")
    keys = KeySpace(ROBOT)
    with SimulatedRobot(bus), EmbeddedRouter() as router:
        master = Master(bus, DEVICES)  # a loaded machine's late heartbeat is not this test's matter
        try:
            patient_controllers(master.nodes.values())
        finally:
            master.close()
        config = AgentConfig(robot=ROBOT, bus=bus, zenoh_connect=(router.endpoint,), timing=PATIENT,
                             record_series=str(tmp_path / "series"))
        with AgentService(config), router.open_client() as session:
            wait_until(lambda: [r for r in session.liveliness().get(keys.agent_alive, timeout=1) if r.ok],
                       timeout_s=PATIENCE_S * 4, what="the agent")
            results = {}
            for theta, seed in ((0.0, 0), (1.0, 0), (1.0, 1), (1.0, 2)):
                request = EpisodeRequest(f"ep{len(results)}", "bracing", (theta,), seed)
                reply, = session.get(keys.episode_run, payload=request.to_json(), timeout=60)
                results[request.episode_id] = EpisodeResult.from_json(reply.ok.payload)
                if theta == 1.0 and results[request.episode_id].failed("hardware_damage"):
                    break
    files = {p.stem: p for p in (tmp_path / "series").glob("*.npz")}
    assert set(files) == set(results) and not list((tmp_path / "series").glob("*.part"))
    series = {eid: read_series(path) for eid, path in files.items()}
    for eid, s in series.items():
        result = results[eid]
        assert result.status == "ok", result
        assert len(s) == result.telemetry["n_cycles"] == 400
        assert np.allclose(np.diff(s.t), 0.005) and s.meta["episode_id"] == eid
        assert s.meta["total_cost"] == result.total_cost and s.meta["failures"] == result.failures
        assert float(np.abs(s.pitch_acc).max()) == pytest.approx(result.telemetry["max_abs_pitch_acc"])
        # bracing holds its pose: the setpoints are the policy's, the same every cycle
        assert not s.spline.any() and np.all(s.setpoint == s.setpoint[0])
        # strike, then the hands stop the fall a few hundred ms later
        t0, contact = strike_s(s), ground_contact_s(s)
        assert t0 is not None and contact is not None and t0 + 0.1 <= contact < t0 + 0.6
    soft, broken = series["ep0"], series[list(results)[-1]]
    assert results[broken.meta["episode_id"]].failed("hardware_damage"), "no stiff episode broke a cable"
    weakest = UBOT.cable_strength_range[0]
    assert soft.cable_tension.max() < weakest  # soft arms stay below every cable's strength
    snaps = [e for e in broken.meta["emcy"] if e["code"] == EmcyCode.CABLE_BROKEN]
    assert snaps
    for e in snaps:  # the tension from the elbow current was near a cable's strength as it broke
        side = 0 if e["device"].endswith("left") else 1
        assert broken.cable_tension[max(e["index"] - 4, 0):e["index"], side].max() > 0.85 * weakest
    out = tmp_path / "episode.png"
    plot_episodes(out, [("soft", soft), ("stiff", broken)])
    assert plt.imread(out).shape[1] > 900
