"""The crowd for a minute (issue 21): 8 clients mixing uploads, deletes, relabels, searches and
moments searches against one real server (SQLite), then against two replicas on one
PostgreSQL database.

Run from the repository root::

    .venv/bin/python bench/bench_crowd.py [--seconds 60] [--no-postgres]

The same clients and checks as ``tests/hardening/test_load.py`` (which runs them for
``MOCAP_CROWD_SECONDS``, 12 s in CI): afterwards the clip count over the API, every index's
count in ``/health``, the stored files and the database agree, and every acknowledged upload
not deleted is there, with its last labels, and found by a search. Prints each operation's
count, rate and latency percentiles, and any problem (exit status 1 then).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from common import ROOT, machine  # bench/common.py (scripts run from bench/)

sys.path.insert(0, str(ROOT))

from tests.hardening.live import LiveServer, database_problems
from tests.hardening.test_load import crowd_problems, crowd_summary, run_crowd, two_replicas


def show(summary: dict[str, object], problems: list[str], errors: list[str]) -> bool:
    head = {k: v for k, v in summary.items() if k != "operations"}
    print(f"  {head}")
    print("  operation | count | per s | p50 ms | p95 ms | p99 ms | max ms | statuses")
    for kind, figures in summary["operations"].items():  # type: ignore[attr-defined]
        print(
            f"  {kind} | {figures['count']} | {figures['per_second']} | {figures['p50']} | "
            f"{figures['p95']} | {figures['p99']} | {figures['max']} | {figures['statuses']}"
        )
    for problem in [*errors[:10], *problems]:
        print(f"  PROBLEM: {problem}")
    return not problems and not errors


def one_server(seconds: float, tmp: Path) -> bool:
    data_dir = tmp / "sqlite" / "data"
    data_dir.parent.mkdir(parents=True)
    # One address for the whole crowd: lift the per-client share as the crowd test does.
    env = {"MOCAP_MAX_K": "100000", "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "64"}
    with LiveServer(data_dir, env) as server:
        ledger, elapsed = run_crowd([server.url], seconds)
        problems = crowd_problems(ledger, [server.url])
    problems += database_problems(data_dir, 3)
    print("one server (SQLite):")
    return show(crowd_summary(ledger, elapsed, 1), problems, ledger.record.errors)


def on_two_replicas(seconds: float, tmp: Path) -> bool:
    from tests import postgres
    from tests.hardening.test_replicas import database_problems as postgres_problems

    cluster = postgres.start_cluster()
    try:
        url = cluster.new_database()
        with two_replicas(tmp, url) as servers:
            urls = [server.url for server in servers]
            ledger, elapsed = run_crowd(urls, seconds)
            problems = crowd_problems(ledger, urls)
        problems += postgres_problems(url)
    finally:
        cluster.stop()
    print("two replicas (PostgreSQL):")
    return show(crowd_summary(ledger, elapsed, 2), problems, ledger.record.errors)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--no-postgres", action="store_true")
    args = parser.parse_args()
    print(f"machine: {machine()}")
    with tempfile.TemporaryDirectory(prefix="mocap-bench-crowd-") as tmp:
        ok = one_server(args.seconds, Path(tmp))
        if not args.no_postgres:
            ok = on_two_replicas(args.seconds, Path(tmp)) and ok
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
