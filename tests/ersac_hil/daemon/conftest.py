"""Fixtures of the daemon tests: a real embedded Zenoh router, the synthetic agent (real
protocol over a real session), in-process daemons on tmp_path stores, polling helpers."""
from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from synthetic_agent import SyntheticAgent  # noqa: E402

from ersac_hil.daemon.config import DaemonConfig  # noqa: E402
from ersac_hil.daemon.service import Daemon  # noqa: E402
from ersac_hil.zenoh_session import EmbeddedRouter  # noqa: E402
from protocol.zenoh import KeySpace  # noqa: E402

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
TIMEOUT = 60.0


def wait_until(predicate: Callable[[], object], timeout_s: float = TIMEOUT, poll_s: float = 0.02) -> object:
    """Poll ``predicate`` until truthy; fail the test on timeout."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"condition not met within {timeout_s} s")
        time.sleep(poll_s)


@pytest.fixture(scope="module")
def router():
    with EmbeddedRouter() as r:
        yield r


@pytest.fixture
def agent_factory(router):
    """Start synthetic agents (each on its own client session) for a robot; closed in teardown."""
    made = []

    def make(robot: str, **kwargs) -> SyntheticAgent:
        session = router.open_client()
        agent = SyntheticAgent(session, KeySpace(robot), **kwargs)
        made.append((agent, session))
        return agent

    yield make
    for agent, session in made:
        agent.close()
        session.close()


@pytest.fixture
def daemon_factory(router, tmp_path):
    """Start in-process daemons (``start()``); each is stopped in teardown."""
    made: list[Daemon] = []

    def make(robot: str, out=None, **kwargs) -> Daemon:  # noqa: ANN001
        kwargs.setdefault("db", tmp_path / f"{robot}.db")
        kwargs.setdefault("seed", 11)
        kwargs.setdefault("resume", "new")
        kwargs.setdefault("backoff_s", (0.05, 0.2))
        config = DaemonConfig(robot=robot, zenoh=(router.endpoint,), **kwargs)
        daemon = Daemon(config, out=out if out is not None else sys.stdout)
        daemon.start()
        made.append(daemon)
        return daemon

    yield make
    for daemon in made:
        daemon.stop()
