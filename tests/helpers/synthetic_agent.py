"""A small stand-in for the robot-side agent that speaks the real protocol over a real Zenoh
session: liveliness token ``agent/alive``, queryable ``episode/run``, ``episode/done``.

Costs come from a known synthetic bracing-like function of (theta, seed), deterministic, so
two runs of the daemon with the same seed see exactly the same costs:

    damage ~ Bernoulli(0.8 * theta**3)              (risk grows with stiffness)
    body_acc_sq = 40 * (1 - 0.75 * theta) * (1 + 0.2 N(0, 1))**2
    arm_power = 0.1 + 0.2 * theta

so J = 10 damage + 0.1 body_acc_sq + 5 arm_power: the mean falls and then rises with theta
while its spread grows. Faults: the first attempt of every episode whose seed is divisible by
``fault_every`` gets ``fault_pdo_timeout`` (deterministic in the request, so retries succeed).

Run standalone: ``python tests/helpers/synthetic_agent.py --robot R --zenoh tcp/127.0.0.1:P
[--delay S] [--fault-every N] [--refuse-above T]``.
"""
from __future__ import annotations

import argparse
import math
import signal
import struct
import sys
import threading
import time

import numpy as np
import zenoh

from ersac_hil.zenoh_session import make_config, open_session
from protocol.zenoh import EpisodeDone, EpisodeRequest, EpisodeResult, ErrorReply, KeySpace, PayloadError


def synthetic_terms(theta: float, seed: int) -> dict[str, float]:
    """The cost terms of one synthetic bracing episode (pure function of theta and seed)."""
    bits = struct.unpack("<Q", struct.pack("<d", float(theta)))[0]
    rng = np.random.default_rng([seed, bits])
    damage = float(rng.random() < 0.8 * theta**3)
    body = 40.0 * (1.0 - 0.75 * theta) * (1.0 + 0.2 * rng.standard_normal()) ** 2
    return {"damage": damage, "body_acc_sq": float(body), "arm_power": 0.1 + 0.2 * theta}


def _episode_index(episode_id: str) -> int:
    """The episode index in the daemon's ids ``<run>.<idx:05d>.<attempt>`` (-1 otherwise)."""
    parts = episode_id.rsplit(".", 2)
    return int(parts[1]) if len(parts) == 3 and parts[1].isdigit() else -1


def true_cost(theta: float) -> tuple[float, float]:
    """Mean and std of the synthetic total cost at theta (default weights)."""
    p = 0.8 * theta**3
    body_mean = 40.0 * (1.0 - 0.75 * theta) * (1.0 + 0.04)
    body_var = (40.0 * (1.0 - 0.75 * theta)) ** 2 * (4 * 0.04 + 2 * 0.04**2)
    mean = 10 * p + 0.1 * body_mean + 5 * (0.1 + 0.2 * theta)
    var = 100 * p * (1 - p) + 0.01 * body_var
    return mean, math.sqrt(var)


class SyntheticAgent:
    """Declares the agent's entities on an open session. ``close()`` undeclares them.

    Args:
        session: an open Zenoh session.
        keys: the robot's key space.
        delay_s: wall time each episode takes (``close()`` ends a running one without a reply).
        fault_every: seeds divisible by this get a fault on their first attempt (0: never).
        always_fault: every episode ends with a fault.
        refuse_above: requests with theta[0] above this get ``reply_err`` ``invalid_request``
            (like the real agent refusing a spline outside the joint limits).
        huge_cost_at: episode indices whose ``body_acc_sq`` is 1e200 (a valid but absurd
            reading: no critic can fit a neighbourhood that holds it).
        rogue: a forger: no liveliness tokens, every request answered at once with schema-valid
            zero costs.
        stopped_first: the first this many requests end ``stopped`` (an e-stop mid-episode).
        unavailable_next: the next this many are refused ``unavailable`` (the e-stop still
            engaged), then episodes run as usual (the operator released it).
        announce: called with every request it starts to run.
    """

    def __init__(self, session: zenoh.Session, keys: KeySpace, delay_s: float = 0.0,
                 fault_every: int = 0, always_fault: bool = False,
                 refuse_above: float = math.inf, huge_cost_at: tuple[int, ...] = (),
                 rogue: bool = False, announce=None, stopped_first: int = 0,
                 unavailable_next: int = 0) -> None:  # noqa: ANN001
        self.keys = keys
        self._held = ["stopped"] * stopped_first + ["unavailable"] * unavailable_next
        self.rogue = rogue
        self.announce = announce
        self.huge_cost_at = set(huge_cost_at)
        self.refuse_above = refuse_above
        self.always_fault = always_fault
        self.delay_s = delay_s
        self.fault_every = fault_every
        self.requests: list[EpisodeRequest] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._tokens = [] if rogue else [
            session.liveliness().declare_token(keys.agent_session(session.info.zid())),
            session.liveliness().declare_token(keys.agent_alive)]
        self._done = session.declare_publisher(keys.episode_done)
        self._queryable = session.declare_queryable(keys.episode_run, self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            request = EpisodeRequest.from_json(query.payload if query.payload is not None else b"")
        except PayloadError as exc:
            query.reply_err(ErrorReply.from_exception(exc).to_json())
            return
        if self.rogue:
            zero = {name: 0.0 for name in request.spec.term_names}
            query.reply(query.key_expr, EpisodeResult(request.episode_id, request.task, "ok", zero,
                                                      0.0).to_json())
            return
        if request.theta[0] > self.refuse_above:
            query.reply_err(ErrorReply("invalid_request", f"theta[0] = {request.theta[0]!r} above the "
                                       f"safe limit {self.refuse_above!r}").to_json())
            return
        if self._held and self._held[0] == "unavailable":
            self._held.pop(0)
            self.requests.append(request)
            query.reply_err(ErrorReply("unavailable", "e-stop engaged (synthetic)").to_json())
            return
        if not self._lock.acquire(blocking=False):
            query.reply_err(ErrorReply("busy", "an episode is running").to_json())
            return
        try:
            self.requests.append(request)
            if self.announce is not None:
                self.announce(request)
            if self.delay_s and self._closed.wait(self.delay_s):
                return  # closed while the episode ran
            attempt = int(request.episode_id.rsplit(".", 1)[-1]) if "." in request.episode_id else 0
            if self._held and self._held[0] == "stopped":
                self._held.pop(0)
                result = EpisodeResult(request.episode_id, request.task, "stopped", {"body_acc_sq": 1.0}, None,
                                       duration_s=0.1, wall_s=self.delay_s, detail="e-stop (synthetic)")
            elif self.always_fault or (self.fault_every and request.seed % self.fault_every == 0
                                     and attempt == 0):
                result = EpisodeResult(request.episode_id, request.task, "fault_pdo_timeout",
                                       {"body_acc_sq": 1.0}, None, duration_s=0.4, wall_s=self.delay_s,
                                       fault_counts={"pdo_timeouts": 1}, detail="synthetic PDO timeout")
            else:
                terms = synthetic_terms(request.theta[0], request.seed)
                if _episode_index(request.episode_id) in self.huge_cost_at:
                    terms["body_acc_sq"] = 1e200
                result = EpisodeResult(
                    request.episode_id, request.task, "ok", terms, request.spec.total_cost(terms),
                    failures={"hardware_damage": terms["damage"] > 0}, duration_s=2.0,
                    wall_s=self.delay_s,
                    telemetry={"n_cycles": 400.0, "max_abs_pitch": 0.1 + 0.3 * request.theta[0],
                               "energy_j": terms["arm_power"]},
                    fault_counts={"emcy": int(terms["damage"])})
            query.reply(query.key_expr, result.to_json())
            self._done.put(EpisodeDone(self.keys.robot, time.time(), request, result).to_json())
        except zenoh.ZError:
            pass  # closed while the episode ran
        finally:
            self._lock.release()

    def close(self) -> None:
        self._closed.set()
        for entity in (self._queryable, self._done, *self._tokens):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - session already closed
                pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--robot", required=True)
    parser.add_argument("--zenoh", required=True)
    parser.add_argument("--delay", type=float, default=0.0)
    parser.add_argument("--fault-every", type=int, default=0)
    parser.add_argument("--refuse-above", type=float, default=math.inf)
    args = parser.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    session = open_session(make_config("client", connect=[args.zenoh], connect_timeout_s=10))
    agent = SyntheticAgent(session, KeySpace(args.robot), args.delay, args.fault_every,
                           refuse_above=args.refuse_above,
                           announce=lambda r: print(f"running {r.episode_id}", flush=True))
    print("synthetic agent ready", flush=True)
    stop.wait()
    agent.close()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
