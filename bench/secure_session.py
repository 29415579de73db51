"""What TLS with client certificates and access control costs, against plain TCP (loopback).

Interleaved in one run (same machine load): ``certs init``; opening a client session; the
round trip of a query/reply with an episode-sized payload through the router; one
``ersac-hil demo`` of a few episodes, plain then ``--secure`` (optional, ``--demo N``).

    python bench/secure_session.py [--rounds 5] [--queries 300] [--demo 5]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ersac_hil.certs import init_certs
from ersac_hil.zenoh_session import (
    EmbeddedRouter, ZenohOptions, free_tcp_port, make_config, open_session, resolve_config,
)
from protocol.zenoh import EpisodeResult, KeySpace, get_task

KEYS = KeySpace("bench")


def _payload() -> bytes:
    terms = {n: 1.0 for n in get_task("bracing").term_names}
    return EpisodeResult("bench-1", "bracing", "ok", terms, 15.1, telemetry={"n_cycles": 400.0}).to_json()


def _stack(secure: bool, certs: Path):
    if secure:
        port = free_tcp_port()
        config = resolve_config(ZenohOptions((f"tls/127.0.0.1:{port}",), str(certs / "router.json5")),
                                mode="router")
        router = EmbeddedRouter(config=config).start()

        def client(role: str):
            return open_session(resolve_config(ZenohOptions((router.endpoint,), str(certs / f"{role}.json5"))))
    else:
        router = EmbeddedRouter().start()

        def client(role: str):
            return open_session(make_config("client", connect=[router.endpoint]))
    return router, client


def _round(secure: bool, certs: Path, queries: int) -> tuple[float, list[float]]:
    router, client = _stack(secure, certs)
    try:
        started = time.perf_counter()
        agent = client("agent")
        opened = time.perf_counter() - started
        daemon = client("daemon")
        payload = _payload()
        queryable = agent.declare_queryable(KEYS.episode_run, lambda q: q.reply(q.key_expr, payload))
        querier = daemon.declare_querier(KEYS.episode_run, timeout=5.0)
        while not querier.matching_status.matching:
            time.sleep(0.001)
        rtts = []
        for _ in range(queries):
            t0 = time.perf_counter()
            replies = list(querier.get(payload=payload))
            rtts.append(time.perf_counter() - t0)
            assert replies and replies[0].ok is not None
        querier.undeclare()
        queryable.undeclare()
        daemon.close()
        agent.close()
        return opened, rtts
    finally:
        router.close()


def _demo(secure: bool, episodes: int, out: Path) -> float:
    started = time.perf_counter()
    cmd = [sys.executable, "-m", "ersac_hil.cli", "demo", "--episodes", str(episodes), "--out", str(out)]
    done = subprocess.run(cmd + (["--secure"] if secure else []), capture_output=True, text=True,
                          env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    if done.returncode != 0:
        return float("nan")
    return time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--queries", type=int, default=300)
    parser.add_argument("--demo", type=int, default=0, metavar="EPISODES",
                        help="also time a demo of this many episodes, plain and --secure")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} at start; interleaved plain/secure rounds")
    with tempfile.TemporaryDirectory() as tmp:
        certs = Path(tmp) / "certs"
        t0 = time.perf_counter()
        init_certs(certs)
        print(f"certs init (CA + 5 roles, P-256): {1000 * (time.perf_counter() - t0):.0f} ms")
        results = {False: ([], []), True: ([], [])}
        demos = {False: [], True: []}
        for r in range(args.rounds):
            for secure in (False, True):
                opened, rtts = _round(secure, certs, args.queries)
                results[secure][0].append(opened)
                results[secure][1].extend(rtts)
            if args.demo and r < 3:
                for secure in (False, True):
                    demos[secure].append(_demo(secure, args.demo, Path(tmp) / f"demo-{secure}"))
        for secure in (False, True):
            opens, rtts = results[secure]
            name = "TLS+mTLS+ACL" if secure else "plain TCP   "
            q = statistics.quantiles(rtts, n=100)
            print(f"{name} open {1000 * statistics.median(opens):6.2f} ms (median of {len(opens)}); "
                  f"query round trip median {1e6 * statistics.median(rtts):6.0f} us, "
                  f"p99 {1e6 * q[98]:6.0f} us ({len(rtts)} queries)")
        for secure in (False, True):
            if demos[secure]:
                name = "demo --secure" if secure else "demo         "
                print(f"{name} {args.demo} episodes: " + ", ".join(f"{t:.1f} s" for t in demos[secure]))
    print(f"load average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
