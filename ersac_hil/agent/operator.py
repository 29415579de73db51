"""``ersac-hil estop`` and ``ersac-hil go``: an operator's commands to the agent, and its state.

    ersac-hil estop [--reason TEXT]     every axis into quick stop, the running episode ends
                                        ``stopped``; the agent stays stopped until released
    ersac-hil estop --release           release it (without a test bench: then wait for go)
    ersac-hil go                        the robot is reset and watched: the next episode may start

Both are puts (``agent/estop``, ``agent/go``) that only the operator role may make (the
router's access control drops an observer's); each is confirmed by asking ``agent/state``
until the agent shows it took effect, so a put that was dropped or reached no agent fails
with exit status 1 and says so. Exit status: 0 confirmed, 1 not confirmed / no agent, 2 usage.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

from ersac_hil.cli_args import UsageError, add_prefix_argument, fail, positive_float

__all__ = ["AgentClient", "register", "agent_state_line"]


class AgentClient:
    """A Zenoh client session on one robot's agent keys."""

    def __init__(self, keys, options, timeout_s: float = 5.0) -> None:  # noqa: ANN001
        from ersac_hil.zenoh_session import open_session, resolve_config
        self.keys, self.timeout_s = keys, timeout_s
        self._session = open_session(resolve_config(options), insecure=options.insecure)

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> "AgentClient":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def state(self, timeout_s: float | None = None):  # noqa: ANN201 - AgentState | None
        """The agent's ``AgentState``, or ``None`` when no agent answers in time."""
        from protocol.zenoh import AgentState, PayloadError
        timeout = self.timeout_s if timeout_s is None else timeout_s
        for reply in self._session.get(self.keys.agent_state, timeout=timeout):
            if reply.ok is None:
                continue
            try:
                return AgentState.from_json(reply.ok.payload)
            except PayloadError:
                continue
        return None

    def put(self, key: str, payload: bytes) -> None:
        self._session.put(key, payload)

    def confirm(self, put: Callable[[], None], done: Callable, timeout_s: float):  # noqa: ANN201
        """Put (again every second: a client's first put may precede its routes) until
        ``done(state)``; the last state seen (``None``: no agent answered)."""
        deadline, state, last_put = time.monotonic() + timeout_s, None, -1.0
        while True:
            now = time.monotonic()
            if now - last_put >= 1.0:
                put()
                last_put = now
            state = self.state(min(1.0, max(deadline - now, 0.1))) or state
            if state is not None and done(state):
                return state
            if time.monotonic() >= deadline:
                return state
            time.sleep(0.05)


def agent_state_line(state) -> str:  # noqa: ANN001
    """``agent     waiting_for_go (real, realtime): ...`` for ``ersac-hil state``."""
    if state is None:
        return "agent     no agent answered on agent/state"
    text = f"agent     {state.phase} ({state.bench} bench, {state.pacing}, {state.episodes} episodes)"
    return f"{text}: {state.detail}" if state.detail else text


def _client(args: argparse.Namespace) -> AgentClient:
    from ersac_hil.zenoh_session import zenoh_options
    from protocol.zenoh import KeySpace
    return AgentClient(KeySpace(args.robot, args.prefix), zenoh_options(args), args.timeout)


def _validate(args: argparse.Namespace) -> None:
    from protocol.zenoh import EstopCommand, KeySpace, PayloadError
    try:
        KeySpace(args.robot, args.prefix)
        if getattr(args, "reason", None) is not None:
            EstopCommand(True, args.reason)
    except (ValueError, PayloadError) as exc:
        raise UsageError(str(exc)) from None


def _estop(args: argparse.Namespace) -> int:
    from protocol.zenoh import EstopCommand
    from ersac_hil.zenoh_session import ZenohConfigError, ZenohSessionError
    engage = not args.release
    payload = EstopCommand(engage, args.reason or ("" if args.release else "ersac-hil estop")).to_json()
    try:
        with _client(args) as client:
            state = client.confirm(lambda: client.put(client.keys.agent_estop, payload),
                                   (lambda s: s.phase == "stopped") if engage else
                                   (lambda s: s.phase != "stopped"), args.timeout)
    except ZenohConfigError as exc:
        return fail("ersac-hil estop", str(exc))
    except ZenohSessionError as exc:
        print(f"ersac-hil estop: {exc}", file=sys.stderr, flush=True)
        return 1
    if state is None:
        print(f"ersac-hil estop: no agent of {args.robot} answered within {args.timeout:g} s: "
              "NOT confirmed - stop the robot by hand", file=sys.stderr, flush=True)
        return 1
    if engage != (state.phase == "stopped"):
        print(f"ersac-hil estop: the agent did not confirm (phase {state.phase}): the put was refused "
              "(only the operator role may put agent/estop) - stop the robot by hand"
              if engage else f"ersac-hil estop: still stopped after {args.timeout:g} s (only the operator "
              "role may release)", file=sys.stderr, flush=True)
        return 1
    print(agent_state_line(state), flush=True)
    return 0


def _go(args: argparse.Namespace) -> int:
    from ersac_hil.zenoh_session import ZenohConfigError, ZenohSessionError
    try:
        with _client(args) as client:
            before = client.state()
            if before is not None and before.phase == "stopped":
                print(f"ersac-hil go: refused: {before.detail}", file=sys.stderr, flush=True)
                return 1
            episodes = before.episodes if before is not None else 0
            state = client.confirm(lambda: client.put(client.keys.agent_go, b"go"),
                                   lambda s: s.phase != "waiting_for_go" or s.episodes > episodes,
                                   args.timeout)
    except ZenohConfigError as exc:
        return fail("ersac-hil go", str(exc))
    except ZenohSessionError as exc:
        print(f"ersac-hil go: {exc}", file=sys.stderr, flush=True)
        return 1
    if state is None or state.phase in ("waiting_for_go", "stopped"):
        why = "no agent answered" if state is None else f"the agent is still {state.phase}"
        print(f"ersac-hil go: not confirmed: {why} (only the operator role may put agent/go)",
              file=sys.stderr, flush=True)
        return 1
    print(agent_state_line(state), flush=True)
    return 0


def _options(p: argparse.ArgumentParser) -> None:
    from ersac_hil.zenoh_session import add_zenoh_arguments
    p.add_argument("--robot", default="ubot1", help="robot name (default ubot1)")
    add_prefix_argument(p)
    add_zenoh_arguments(p)
    p.add_argument("--timeout", type=positive_float, default=5.0,
                   help="seconds to wait for the agent to confirm (default 5)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("estop", help="emergency stop: every axis into quick stop, the episode ends 'stopped'")
    p.add_argument("--release", action="store_true", help="release the e-stop instead")
    p.add_argument("--reason", help="who stops it and why (shown in the agent's state)")
    _options(p)
    p.set_defaults(func=_estop, validate=_validate)
    p = sub.add_parser("go", help="the robot is reset and watched: the agent may start the next episode")
    _options(p)
    p.set_defaults(func=_go, validate=_validate)


def print_agent_state(args: argparse.Namespace) -> None:
    """One line on the agent of ``args.robot`` (``ersac-hil state``); never fails the command."""
    try:
        with _client(args) as client:
            state = client.state(min(args.timeout, 2.0))
    except Exception as exc:  # noqa: BLE001 - the learner's state was the command's answer
        print(f"agent     not reachable: {exc}", flush=True)
        return
    print(agent_state_line(state), flush=True)
