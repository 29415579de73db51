"""Reports from a real store written by a daemon run against the synthetic agent."""
from __future__ import annotations

import json
import statistics
import warnings

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.colors import to_rgb

from ersac_hil.cli import main
from ersac_hil.daemon.clients import LearnerClient
from ersac_hil.daemon.critic_plots import TRADE_OFF_KAPPAS
from ersac_hil.daemon.report import write_report
from ersac_hil.daemon.store import Store
from protocol.zenoh import KeySpace


def test_report_files_and_summary(router, agent_factory, daemon_factory, tmp_path, capsys):
    agent_factory("rep", fault_every=6)
    daemon = daemon_factory("rep", episodes=15, kappa=2.0)
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    with LearnerClient(KeySpace("rep"), [router.endpoint]) as client:
        final = client.state()
    daemon.stop()
    out = tmp_path / "report"
    summary = write_report(daemon.config.db, daemon.learning.run_id, out)
    assert summary == json.loads((out / "summary.json").read_text())
    for name in ("learning_curve.png", "critic.png", "risk.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert "episode.png" not in summary["files"]  # no time series recorded (agent --record-series)
    # the risk trade-off of the run's critic: one offline selection per kappa 0..4; a larger
    # kappa never buys more risk (the minimiser of J~ + kappa r~ over the same region)
    by_kappa = summary["selection_by_kappa"]
    assert [sel["kappa"] for sel in by_kappa] == list(TRADE_OFF_KAPPAS)
    for a, b in zip(by_kappa, by_kappa[1:]):  # SLSQP's tolerances: 1e-3 relative
        assert b["r"] <= a["r"] * (1 + 1e-3) and b["J"] >= a["J"] * (1 - 1e-3), (a, b)
        assert b["F"] == pytest.approx(b["J"] + b["kappa"] * b["r"])
    with Store(daemon.config.db, readonly=True) as store:
        episodes = store.ok_episodes(daemon.learning.run_id)
        costs = [e.cost for e in episodes]
        attempts = store.attempts(daemon.learning.run_id)
    # hardware damage is red in the critic plot (the paper's Figs. 1-2), and nothing else is
    pixels = plt.imread(out / "critic.png")[..., :3]
    red = np.all(np.abs(pixels - np.array(to_rgb("tab:red"))) < 0.02, axis=-1).sum()
    assert (red > 20) == any(e.failures["hardware_damage"] for e in episodes)
    assert summary["episodes"] == 15 and summary["attempts"] == len(attempts)
    assert summary["attempts_by_status"]["fault_pdo_timeout"] == len(attempts) - 15
    assert tuple(summary["final_theta"]) == final.theta and summary["kappa"] == 2.0
    assert summary["cost"]["all"]["mean"] == pytest.approx(statistics.fmean(costs))
    assert summary["cost"]["last_10"]["mean"] == pytest.approx(statistics.fmean(costs[-10:]))
    assert summary["cost"]["all"]["max"] == max(costs) and summary["wall_time_s"] > 0
    critic = summary["critic_at_final_theta"]
    assert critic["F"] == pytest.approx(critic["J"] + 2.0 * critic["r"]) and critic["r"] > 0

    assert main(["report", daemon.learning.run_id, "--db", str(daemon.config.db), "--out", str(tmp_path / "cli")]) == 0
    assert "summary.json" in capsys.readouterr().out
    assert main(["report", "latest", "--db", str(daemon.config.db), "--out", str(tmp_path / "l")]) == 0
    assert json.loads((tmp_path / "l" / "summary.json").read_text())["run_id"] == daemon.learning.run_id
    assert main(["report", "no-such-run", "--db", str(daemon.config.db), "--out", str(tmp_path / "x")]) == 2
    assert main(["report", "x", "--db", str(tmp_path / "missing.db"), "--out", str(tmp_path / "y")]) == 2


@pytest.mark.parametrize("episodes", [1, 2])
def test_a_run_too_short_for_a_critic_is_reported_without_critic_figures(router, agent_factory,
                                                                          daemon_factory, tmp_path, episodes):
    """Fewer ok episodes than a critic can be fitted on (``demo --episodes 2``): the learning curve
    and the summary, no critic, risk or selection, and no error."""
    agent_factory(f"short{episodes}")
    daemon = daemon_factory(f"short{episodes}", episodes=episodes, kappa=2.0)
    assert daemon.finished.wait(60) and daemon.exit_code == 0
    daemon.stop()
    out = tmp_path / "report"
    summary = write_report(daemon.config.db, daemon.learning.run_id, out)
    assert summary["files"] == ["learning_curve.png", "summary.json"] and summary["episodes"] == episodes
    assert summary["critic_at_final_theta"] is None and summary["selection_by_kappa"] is None
    assert (out / "learning_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_run_without_an_episode_is_reported_without_a_warning(router, daemon_factory, tmp_path):
    """A run whose agent never came (exit 4, resumable) has no episode: its report is the
    learning curve's empty axes and the summary, and matplotlib says nothing (it warned of
    legends with no artists)."""
    daemon = daemon_factory("nobody", episodes=3, kappa=2.0, agent_wait_s=0.5)
    assert daemon.finished.wait(60) and daemon.exit_code == 4
    daemon.stop()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        summary = write_report(daemon.config.db, daemon.learning.run_id, tmp_path / "report")
    assert summary["episodes"] == 0 and summary["files"] == ["learning_curve.png", "summary.json"]
