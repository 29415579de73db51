"""Fixtures of the daemon tests: a real embedded Zenoh router, the synthetic agent (real
protocol over a real session), in-process daemons on tmp_path stores."""
from __future__ import annotations

import os
import sys

import pytest

from ersac_hil.daemon.config import DaemonConfig
from ersac_hil.daemon.service import Daemon
from ersac_hil.zenoh_session import EmbeddedRouter
from helpers.synthetic_agent import SyntheticAgent
from protocol.zenoh import KeySpace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


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
