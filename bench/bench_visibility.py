"""How soon one replica sees what another stored or deleted: the README's promise, "within
``MOCAP_INDEX_REFRESH_SECONDS`` + 1 s", measured (the test of two replicas,
``tests/hardening/test_replicas.py``, only checks that it happens).

Run from the repository root (PostgreSQL 15 installed, as for the tests)::

    .venv/bin/python bench/bench_visibility.py [--clips 40] [--refresh 0.1]

Starts a throwaway PostgreSQL server and two ``mocap-index serve`` replicas on it (their own
data directories, as on two machines), uploads ``--clips`` unique real clips through A one at
a time and times, for each, until a search through B returns it; then deletes them through A
and times until B no longer returns them. Prints the median, 95th percentile and maximum
against the promise, and the load average (the machine is shared).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx
from common import ROOT, machine

sys.path.insert(0, str(ROOT))

from tests.hardening.live import LiveServer, unique_upload  # (after the path is set)
from tests.postgres import start_cluster


def seconds_until(condition: object, limit: float = 60.0) -> float:
    started = time.perf_counter()
    while not condition():  # type: ignore[operator]
        if time.perf_counter() - started > limit:
            raise SystemExit(f"not visible within {limit} s: the change feed is broken")
        time.sleep(0.005)
    return time.perf_counter() - started


def found(client: httpx.Client, query: int) -> set[int]:
    answer = client.get("/search", params={"clip": query, "k": 100_000})
    answer.raise_for_status()
    return {hit["id"] for hit in answer.json()["results"]}


def summary(values: list[float], promise: float) -> str:
    ordered = sorted(values)
    p95 = ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))]
    late = sum(v > promise for v in values)
    return (
        f"median {statistics.median(values) * 1000:.0f} ms, p95 {p95 * 1000:.0f} ms, "
        f"max {ordered[-1] * 1000:.0f} ms; {late} of {len(values)} later than "
        f"{promise * 1000:.0f} ms"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", type=int, default=40)
    parser.add_argument("--refresh", type=float, default=0.1)
    args = parser.parse_args()
    promise = args.refresh + 1.0
    print(f"machine: {machine()}")
    cluster = start_cluster()
    work = Path(tempfile.mkdtemp(prefix="bench-visibility-"))
    env = {
        "MOCAP_DATABASE_URL": cluster.new_database(),
        "MOCAP_INDEX_REFRESH_SECONDS": str(args.refresh),
        "MOCAP_MAX_K": "100000",
    }
    (work / "a").mkdir()
    (work / "b").mkdir()
    a, b = LiveServer(work / "a" / "data", env), LiveServer(work / "b" / "data", env)
    try:
        a.start()
        b.start()
        with (
            httpx.Client(base_url=a.url, timeout=60) as ca,
            httpx.Client(base_url=b.url, timeout=60) as cb,
        ):
            first = ca.post("/clips", files=unique_upload(0)).json()["id"]
            stored, deleted, ids = [], [], []
            for n in range(1, args.clips + 1):
                clip = ca.post("/clips", files=unique_upload(n)).json()["id"]
                ids.append(clip)
                stored.append(seconds_until(lambda c=clip: c in found(cb, first)))
            for clip in ids:
                assert ca.delete(f"/clips/{clip}").status_code == 204
                deleted.append(seconds_until(lambda c=clip: c not in found(cb, first)))
    finally:
        a.stop()
        b.stop()
        cluster.stop()
        shutil.rmtree(work, ignore_errors=True)
    print(f"refresh {args.refresh} s, {args.clips} clips, load average {os.getloadavg()[0]:.2f}")
    print(f"stored through A, found through B : {summary(stored, promise)}")
    print(f"deleted through A, gone through B : {summary(deleted, promise)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
