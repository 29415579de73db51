"""``reproduce bracing --quick`` end to end through every real process, on pairs it starts
(``--pairs 2``: interrupted with Ctrl-C, no child left, exit 130; run again, it resumes; the
results files and figures), and ``reproduce`` and ``bench/bracing_sweep.py`` on simulator/agent
pairs already running elsewhere behind a router (``--agents KEYEXPR --zenoh-config FILE``), the
same code path as the pairs they start themselves, with the same results. The quick run on the
pairs it starts is made once (``quick_local``), and the run on the pairs elsewhere is compared
with it: the same results.json, interrupted and resumed or not.

The pairs: a TLS router with the roles' access control (``ersac-hil certs init``), two
simulators and two agents (robots ubot1, ubot2) started as a user starts them on other machines.
With root they run in a network namespace this module makes, and the requester (``reproduce``,
its daemons, the sweep) in another, joined by a veth pair: the router is reached only over it.
Without namespaces they run on loopback and the namespace test is skipped with the reason.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ersac_hil.certs import init_certs
from ersac_hil.cli import main as cli_main
from ersac_hil.daemon.store import Store
from ersac_hil.daemon.discovery import NoAgents, find_agents
from ersac_hil.stack import Child, child_env, cli_argv
from ersac_hil.zenoh_session import (EmbeddedRouter, ZenohOptions, add_zenoh_arguments, free_tcp_port,
                                     open_session, session_scope, zenoh_argv, zenoh_options)
from ersac_hil.stack.faults import START_S, Netns, netns_unavailable
from helpers.processes import children, gone, group_killed_on_exit, lines_until, running_with
from helpers.synthetic_agent import SyntheticAgent
from helpers.waiting import wait_until
from protocol.zenoh import DEFAULT_PREFIX, KeySpace

ROOT = Path(__file__).resolve().parents[2]
ENV = {**child_env(), "PYTHONUNBUFFERED": "1"}
ROBOTS = ("ubot1", "ubot2")
NOT_COMPARED = ("timing", "pairs", "agents")
"""``results.json`` ``meta`` fields that say where and how fast, not what came out."""
PNG = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- the pairs elsewhere
@dataclass
class Site:
    """The robot side (router, simulators, agents) and where the requester runs."""

    work: Path
    netns: Netns | None
    endpoint: str
    configs: dict[str, Path]
    why_not_netns: str | None = None
    children: list[Child] = field(default_factory=list)

    def requester(self, argv: list[str]) -> list[str]:
        """``argv`` as the requester runs it (inside the daemon's namespace with one)."""
        return [*self.netns.prefix(self.netns.daemon), *argv] if self.netns else argv

    def launch(self, name: str, argv: list[str]) -> Child:
        prefix = self.netns.prefix(self.netns.robot) if self.netns else []
        child = Child(name, [*prefix, *argv], self.work, ENV)
        self.children.append(child)
        return child

    def close(self) -> None:
        for child in reversed(self.children):
            child.stop()
        if self.netns is not None:
            self.netns.close()


def start_site(work: Path, netns: Netns | None) -> Site:
    """A TLS router and two simulator/agent pairs, each command as docs/reproduce.md gives it."""
    host = Netns.ROBOT_IP if netns else "127.0.0.1"
    endpoint = f"tls/{host}:{free_tcp_port()}"  # a fresh namespace has every port free
    certs = init_certs(work / "certs", router=(endpoint,))
    site = Site(work, netns, endpoint, dict(certs.configs))
    try:
        router = site.launch("router", cli_argv("router", "--zenoh", endpoint, "--zenoh-config",
                                                str(certs.configs["router"])))
        sims = []  # started beside the router: their CAN links do not go through it
        for k, robot in enumerate(ROBOTS, 1):
            listen = f"tcp/127.0.0.1:{free_tcp_port()}"  # the robot's own CAN link, on its loopback
            sims.append((robot, listen, site.launch(f"sim-{robot}", cli_argv(
                "sim", "--bus-interface", "zenoh", "--bus-channel", robot, "--bus-kwargs", f"listen={listen}",
                "--seed", str(k)))))
        router.wait_for(r"Zenoh router: ", START_S)
        agents = []
        for robot, listen, sim in sims:  # each agent once its simulator listens; the agents start together
            sim.wait_for(r"^simulator: \d+ nodes", START_S)
            agents.append(site.launch(f"agent-{robot}", cli_argv(
                "agent", "--robot", robot, "--bus-interface", "zenoh", "--bus-channel", f"{robot}@{listen}",
                "--zenoh", endpoint, "--zenoh-config", str(certs.configs["agent"]))))
        for agent in agents:
            agent.wait_for(r"^agent ready: ", START_S)
    except BaseException:
        site.close()
        raise
    return site


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Iterator[Site]:
    why = netns_unavailable()
    netns = Netns() if why is None else None
    try:
        s = start_site(tmp_path_factory.mktemp("fleet-site"), netns)
    except BaseException:
        if netns is not None:
            netns.close()
        raise
    s.why_not_netns = why
    try:
        yield s
    finally:
        s.close()
        assert all(not c.alive() for c in s.children)
        if netns is not None:
            listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
            assert netns.daemon not in listed and netns.robot not in listed, listed


def _comparable(out: Path) -> dict:
    results = json.loads((out / "results.json").read_text())
    for key in NOT_COMPARED:
        results["meta"].pop(key, None)
    return results


def _run(argv: list[str], timeout_s: float) -> tuple[int, str, float]:
    """Run ``argv`` to its end: (exit code, output, wall seconds)."""
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    with group_killed_on_exit(proc):
        text, _ = proc.communicate(timeout=timeout_s)
    return proc.returncode, text, time.monotonic() - t0


def _reproduce(*args: str) -> list[str]:
    return [sys.executable, "-m", "ersac_hil.cli", "reproduce", "bracing", "--quick", *args]


# --------------------------------------------------------------------------- on pairs it starts
@dataclass(frozen=True)
class QuickRun:
    """``reproduce bracing --quick --pairs 2`` into ``out``: ``first``, the output of the start
    interrupted by SIGINT once a few episodes were stored (exit ``first_code``); ``second``, the
    output of the same command run again to its end (exit ``second_code``)."""

    out: Path
    first: str
    first_code: int
    second: str
    second_code: int


@pytest.fixture(scope="module")
def quick_local(tmp_path_factory) -> QuickRun:
    """The module's one quick run on pairs it starts: interrupted, then resumed to its end."""
    out = tmp_path_factory.mktemp("quick-local") / "results"
    argv = _reproduce("--pairs", "2", "--out", str(out))
    proc = subprocess.Popen(argv, cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    with group_killed_on_exit(proc):
        lines = lines_until(proc, r"\] ([3-9]|\d\d)/\d+ episodes", 180)  # a few episodes are stored
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=60)
    first, first_code = "".join(lines) + rest, proc.returncode
    code, second, _ = _run(argv, 600) if first_code == 130 else (-1, "(not run again)", 0.0)
    return QuickRun(out, first, first_code, second, code)


@pytest.mark.slow
@pytest.mark.timeout(900)  # --quick is 55 episodes: minutes on a loaded 2-core machine
def test_quick_bracing_is_interrupted_resumed_and_reported(quick_local):
    out, first, second = quick_local.out, quick_local.first, quick_local.second
    assert quick_local.first_code == 130 and "interrupted" in first, first
    assert all(gone(pid) for pid in children(first).values()) and not running_with(out), first
    stored = int(re.findall(r"\] (\d+)/\d+ episodes", first)[-1])

    assert quick_local.second_code == 0, second
    match = re.search(r"(\d+) episodes to have \((\d+) already stored\)", second)
    assert match and int(match.group(2)) >= stored > 0, second
    assert not running_with(out)

    results = json.loads((out / "results.json").read_text())
    bracing = results["bracing"]
    assert len(bracing["final_theta"]["kappa_2"]) == len(bracing["final_theta"]["kappa_0"]) == 2
    assert math.isfinite(bracing["paired"]["wilcoxon_p_one_sided"])  # two paired differences
    assert bracing["landscape"]["episodes_per_theta"] == 2 and len(bracing["landscape"]["rows"]) == 2
    assert {t["target"].split(":")[0] for t in results["targets"]} >= {"landscape", "bracing"}
    assert "| run seed |" in (out / "results.md").read_text()
    for name in ("bracing_landscape.png", "bracing_runs.png", "fig1_critic.png", "fig2_critic.png"):
        assert (out / name).read_bytes()[:8] == PNG, name
    for kappa, seed in ((k, s) for k in ("2", "0") for s in (1, 2)):
        with Store(out / "runs" / f"bracing-k{kappa}-s{seed}.db", readonly=True) as store:
            (run,) = store.runs()
            assert run.status == "finished" and len(store.ok_episodes(run.run_id)) == 12
            assert run.settings["eta"] == 0.7 and run.settings["sigma"] == [0.05]  # the paper's
            moves = [u for u in store.updates(run.run_id) if u.theta_after != u.theta_before]
            assert moves, "the learner never moved theta: the quick run is inside its warm-up"


# --------------------------------------------------------------------------- the same results
@pytest.mark.slow
@pytest.mark.timeout(1800)  # a --quick run of 55 episodes: minutes on a loaded 2-core machine
def test_the_fleet_variant_of_reproduce_bracing_quick_gives_the_local_results_json(site, quick_local, tmp_path):
    """``reproduce bracing --quick`` on the two pairs of ``site`` behind their router
    (``--agents 'ubot$*' --zenoh-config daemon.json5``) and on two pairs it starts
    (``quick_local``, interrupted and resumed): the same results.json but for where and how
    fast; both agents ran learning runs; nothing left."""
    local, fleet = quick_local.out, tmp_path / "fleet"
    assert quick_local.second_code == 0, quick_local.second
    code, text, wall_fleet = _run(site.requester(_reproduce(
        "--agents", "ubot$*", "--zenoh-config", str(site.configs["daemon"]), "--out", str(fleet))), 900)
    assert code == 0, text
    assert "on 2 agent(s) behind the router (ubot1, ubot2)" in text, text
    print(f"reproduce bracing --quick: fleet 2 agents {wall_fleet:.0f} s, load {os.getloadavg()[0]:.1f}")

    assert _comparable(fleet) == _comparable(local)
    meta = json.loads((fleet / "results.json").read_text())["meta"]
    assert meta["agents"] == {"source": "ubot$*", "robots": list(ROBOTS)} and meta["pairs"] == 2
    served = {line.split("--robot ")[1].split()[0]
              for log in (fleet / "logs").glob("daemon-*.log") for line in log.read_text().splitlines()[:1]}
    assert served == set(ROBOTS), served  # the learning runs went to both agents
    assert not running_with(local) and not running_with(fleet)
    assert all(c.alive() for c in site.children)  # the pairs elsewhere are not ours to stop


def test_the_pairs_run_in_their_own_network_namespace(site):
    """The router and the pairs are in the robot's namespace, the requester reaches them over
    the veth only (skipped, with the reason, where namespaces cannot be made)."""
    if site.netns is None:
        pytest.skip(site.why_not_netns)
    ns = site.netns
    for child in site.children:
        assert os.readlink(f"/proc/{child.pid}/ns/net") != os.readlink("/proc/self/ns/net"), child.name
    assert site.endpoint.startswith(f"tls/{Netns.ROBOT_IP}:")
    code, text, _ = _run(site.requester([sys.executable, "-c", "import os; print(os.readlink('/proc/self/ns/net'))"]),
                         60)
    assert code == 0 and text.strip() not in (os.readlink("/proc/self/ns/net"),
                                               os.readlink(f"/proc/{site.children[0].pid}/ns/net")), text
    assert ns.daemon != ns.robot


def test_bracing_sweep_in_process_on_pairs_it_starts_and_on_agents_elsewhere_is_bit_for_bit_the_same(site, tmp_path):
    """``bench/bracing_sweep.py`` in its own process, on one pair it starts (``--pairs 1``) and
    on the pairs of ``site`` (``--agents 'ubot$*'``): the same landscape and episodes (2 each)."""
    sweep = [sys.executable, str(ROOT / "bench" / "bracing_sweep.py"), "--thetas", "0.5", "--episodes", "2",
             "--bootstrap", "20"]
    runs = {"here": sweep, "pairs": [*sweep, "--pairs", "1"],
            "agents": site.requester([*sweep, "--agents", "ubot$*", "--zenoh-config", str(site.configs["daemon"])])}
    docs = {}
    for name, argv in runs.items():
        code, text, _ = _run([*argv, "--out", str(tmp_path / name)], 600)
        assert code == 0, text
        docs[name] = json.loads((tmp_path / name / "landscape.json").read_text())
        for key in ("wall_s", "reruns"):
            docs[name].pop(key)
    assert "on 2 agent(s) behind the router: ubot1, ubot2" in text, text
    assert docs["pairs"] == docs["here"] and docs["agents"] == docs["here"]
    assert not running_with(tmp_path)


# --------------------------------------------------------------------------- refusals
def _refused(argv: list[str], capsys) -> str:  # noqa: ANN001
    """``ersac-hil ARGV``'s one-line refusal (exit 2, nothing on stdout)."""
    code = cli_main(argv)
    captured = capsys.readouterr()
    assert code == 2 and not captured.out.strip(), captured
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    return lines[0]


@pytest.mark.parametrize("flags, says", [
    (["--pairs", "2", "--agents", "ubot$*"], "--pairs and --agents exclude each other"),
    (["--zenoh-config", "x.json5"], "--zenoh-config only with --agents"),
    (["--zenoh", "tcp/127.0.0.1:7447", "--agent-wait", "3"], "--zenoh, --agent-wait only with --agents"),
    (["--agents", "ubot/1"], "is neither a robot name nor a one-chunk key expression"),
    (["--agents", "ubot$*", "--agent-wait", "0"], "--agent-wait must be in (0, 3600]"),
    (["--agents", "ubot$*", "--zenoh-config", "{missing}"], "no such file"),
    (["--agents", "ubot$*", "--zenoh-config", "{garbage}"], "is not a valid Zenoh json5 config"),
])
def test_a_refused_combination_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, flags, says):
    (tmp_path / "garbage.json5").write_text("{ mode: 'client', connect: ")
    flags = [f.format(missing=tmp_path / "missing.json5", garbage=tmp_path / "garbage.json5") for f in flags]
    out = tmp_path / "out"
    assert says in _refused(["reproduce", "bracing", "--quick", "--out", str(out), *flags], capsys)
    assert not out.exists()


def test_an_identity_whose_role_may_not_request_episodes_is_not_permitted(tmp_path, capsys):
    """An observer's certificate: refused before anything is sent, "not permitted"."""
    certs = init_certs(tmp_path / "certs", router=(f"tls/127.0.0.1:{free_tcp_port()}",))
    out = tmp_path / "out"
    line = _refused(["reproduce", "bracing", "--quick", "--out", str(out), "--agents", "ubot$*",
                     "--zenoh-config", str(certs.configs["observer"])], capsys)
    assert "not permitted: observer may not request episodes" in line and "timed out" not in line
    assert not out.exists()


def test_an_identity_the_routers_access_control_does_not_know_is_told_not_permitted(site, tmp_path):
    """A certificate of the fleet's CA whose name is no role ('intruder'): the router admits the
    session and its access control drops everything unseen; after the wait the refusal says
    "not permitted?" and why, not only that nothing answered."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    from ersac_hil import certs

    made = site.configs["daemon"].parent
    ca_key = serialization.load_pem_private_key((made / "ca.key").read_bytes(), None)
    ca = x509.load_pem_x509_certificate((made / "ca.crt").read_bytes())
    key = ec.generate_private_key(ec.SECP256R1())
    (tmp_path / "ca.crt").write_bytes((made / "ca.crt").read_bytes())
    (tmp_path / "intruder.key").write_bytes(certs._key_pem(key))
    (tmp_path / "intruder.crt").write_bytes(
        certs._issue("intruder", key, ca_key, ca.subject, 1).public_bytes(serialization.Encoding.PEM))
    config = tmp_path / "intruder.json5"
    config.write_bytes(certs._json5("intruder", certs.client_config("intruder", tmp_path, [site.endpoint])))
    out = tmp_path / "out"
    code, text, _ = _run(site.requester(_reproduce("--out", str(out), "--agents", "ubot$*", "--zenoh-config",
                                                   str(config), "--agent-wait", "2")), 120)
    lines = text.strip().splitlines()
    assert code == 2 and len(lines) == 1, text
    assert "0 answered" in text and "not permitted? this identity, 'intruder', is no role" in text, text
    assert not out.exists()


def test_a_key_expression_no_agent_answers_says_how_many_did(tmp_path, capsys):
    """A router with one agent, lab1, and ``--agents 'ubot$*'``: refused after the wait, saying
    0 answered and which agents under the prefix did."""
    out = tmp_path / "out"
    with EmbeddedRouter() as router:
        session = open_session(router.client_config())
        agent = SyntheticAgent(session, KeySpace("lab1"))
        try:
            line = _refused(["reproduce", "bracing", "--quick", "--out", str(out), "--agents", "ubot$*",
                             "--zenoh", router.endpoint, "--agent-wait", "1"], capsys)
            assert "no agent answered on ersac/ubot$*/agent/alive within 1 s (0 answered" in line, line
            assert "lab1" in line
            line = _refused(["reproduce", "bracing", "--quick", "--out", str(out), "--agents", "*",
                             "--zenoh", f"tcp/127.0.0.1:{free_tcp_port()}", "--agent-wait", "1"], capsys)
            assert "cannot open a zenoh session" in line, line  # nothing listens there
        finally:
            agent.close()
            session.close()
    assert not out.exists()


@given(st.lists(st.sampled_from(["tcp/127.0.0.1:7447", "tls/10.0.0.1:7448", "tcp/[::1]:1"]), max_size=3),
       st.one_of(st.none(), st.sampled_from(["a.json5", "/etc/ersac/daemon.json5"])), st.booleans())
def test_the_zenoh_flags_given_to_a_child_are_the_options_they_came_from(endpoints, config, insecure):
    options = ZenohOptions(tuple(endpoints), config, insecure)
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    assert zenoh_options(parser.parse_args(zenoh_argv(options))) == options


def test_find_agents_gives_every_ready_agent_the_key_expression_matches_and_nothing_else():
    """Each look-up on a session of its own, as ``reach_agents`` opens one."""
    with EmbeddedRouter() as router:
        sessions = [open_session(router.client_config()) for _ in range(4)]  # 3 agents, 1 onlooker
        agents = [SyntheticAgent(s, KeySpace(robot)) for s, robot in zip(sessions, ("ubot1", "ubot2", "lab1"))]

        def find(source: str, wait_s: float) -> list[str]:
            with session_scope(router.client_config()) as session:
                return find_agents(session, DEFAULT_PREFIX, source, wait_s, threading.Event())

        try:
            tokens = f"{DEFAULT_PREFIX}/*/agent/alive"
            wait_until(lambda: len(list(sessions[3].liveliness().get(tokens, timeout=5.0))) == 3,
                       what="the three agents' tokens at the router")
            assert find("ubot$*", 30.0) == ["ubot1", "ubot2"]
            assert find("lab1", 30.0) == ["lab1"]
            with pytest.raises(NoAgents, match=r"0 answered; agents of other robots under ersac/ did: lab1, ubot1, "
                                                r"ubot2\)"):
                find("ubot3", 0.5)
        finally:
            for agent in agents:
                agent.close()
            for s in sessions:
                s.close()
