"""Replicas on PostgreSQL: search throughput and how fast a fresh replica is ready.

Run from the repository root (``wrk`` and PostgreSQL 15 must be installed: ``apt-get install
-y wrk postgresql-15``)::

    .venv/bin/python bench/bench_replicas.py [--count 100000] [--duration 15]

1. Fill: a SQLite library and a PostgreSQL database (a throwaway server in a temporary
   directory, as the tests start: ``tests/postgres.py``) to ``--count`` clips each, with
   ``mocap-index import`` of the Bandai dataset 1 (when ``../shared/data`` has it) and
   ``mocap-index fill-synthetic``.
2. Fresh replica: ``mocap-index serve`` on the PostgreSQL database with an empty data
   directory (no index files: every index is rebuilt from the database), timed from process
   start until ``/health`` answers 200; then the same replica restarted (index files loaded).
3. Load: ``wrk`` with ``bench/search.lua`` (random clip ids, every answer checked), 32
   connections for ``--duration`` seconds after a warm-up, against one replica on SQLite, one
   on PostgreSQL, and two on PostgreSQL (two ``wrk`` runs of 16 connections at once, one per
   replica, their requests/s added: what a round-robin proxy in front of them would see,
   without the proxy's own cost).

With ``--rebuild-at N`` it only times a fresh replica's rebuild of every index from a
PostgreSQL database of ``N`` clips (e.g. 1,000,000), filled in bulk on the server
(``generate_series`` for the clip rows, ``COPY`` for clustered random vectors: minutes
instead of the ``fill-synthetic`` run's quarter of an hour), in this process: reading the
vectors, then ``open_library`` on an empty data directory.

Everything runs on one machine: the replicas, PostgreSQL and ``wrk`` share its cores, so two
replicas cannot be faster than the cores allow. Loopback only; every wait is bounded.
"""

from __future__ import annotations

import argparse
import os
import pwd
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench_search import CLI, Server, environment, wrk
from common import ROOT, machine, shared_data

sys.path.insert(0, str(ROOT))

from tests.postgres import Cluster, bin_dir  # (after the path is set)


def fill(count: int, data_dir: Path, database_url: str | None) -> float:
    """Seconds to fill the library to ``count`` clips."""
    started = time.perf_counter()
    where = ["--data-dir", str(data_dir)]
    if database_url:
        where += ["--database-url", database_url]
    bandai = shared_data() / "bandai-ds1"
    if bandai.is_dir():
        subprocess.run(
            [CLI, "import", "--no-progress", *where, str(bandai)], check=True, env=environment()
        )
    subprocess.run(
        [CLI, "fill-synthetic", "--count", str(count), *where],
        check=True,
        env=environment(),
        stdout=subprocess.DEVNULL,
    )
    return time.perf_counter() - started


def bulk_fill(url: str, count: int, seed: int = 7) -> None:
    """``count`` synthetic clips with vectors around 200 random centres, straight into the
    database (the triggers fill the change feed as for any insert)."""
    import numpy as np
    import psycopg

    from app.config import Settings
    from app.services.describe import MotionDescriber

    descriptors = MotionDescriber.from_settings(Settings()).descriptors.values()
    rng = np.random.default_rng(seed)
    with psycopg.connect(url.replace("+psycopg", ""), autocommit=True) as db:
        db.execute(
            "INSERT INTO clips (name, format, content_hash, frame_count, frame_time, duration, "
            "joint_count, skeleton_family, lead_in_frames, created_at) SELECT 'bulk-' || g, "
            "'synthetic', md5(g::text) || md5((g + 1)::text), 300, 1 / 30.0, 10, 25, "
            "'synthetic', 0, now() FROM generate_series(1, %s) g",
            (count,),
        )
        for info in descriptors:
            centres = rng.normal(size=(200, info.dimension)).astype(np.float32)
            with db.cursor().copy(
                "COPY clip_descriptors (clip_id, name, version, dimension, vector) FROM STDIN"
            ) as copy:
                for start in range(0, count, 100_000):
                    n = min(100_000, count - start)
                    noisy = centres[rng.integers(0, 200, n)] + 0.3 * rng.normal(
                        size=(n, info.dimension)
                    ).astype(np.float32)
                    for i, vector in enumerate(noisy.astype("<f4")):
                        copy.write_row(
                            (
                                start + i + 1,
                                info.name,
                                info.version,
                                info.dimension,
                                vector.tobytes(),
                            )
                        )


def time_rebuild(url: str, count: int, work: Path) -> None:
    from app.config import Settings
    from app.db import vectors as vector_db
    from app.services.library import open_library

    started = time.perf_counter()
    bulk_fill(url, count)
    print(f"PostgreSQL filled in bulk to {count} clips in {time.perf_counter() - started:.0f} s")
    settings = Settings(data_dir=work / "rebuild", database_url=url)
    library = open_library(settings)  # builds the indexes (timed below, on a second replica)
    try:
        started = time.perf_counter()
        with library.reads() as session:
            for info in library.descriptors.values():
                vector_db.load_vectors(session, info.name, info.version, info.dimension)
        print(f"reading every vector from PostgreSQL: {time.perf_counter() - started:.1f} s")
    finally:
        library.close()
    started = time.perf_counter()
    fresh = open_library(settings.model_copy(update={"data_dir": work / "rebuild-2"}))
    kinds = ", ".join(index.kind for index in fresh.indexes.values())
    print(f"fresh replica, {count} clips: indexes rebuilt in {time.perf_counter() - started:.1f} s")
    print(f"index kinds: {kinds}")
    fresh.close()


def load(servers: list[Server], connections: int, seconds: int, clips: int) -> dict[str, float]:
    """``connections`` spread evenly over ``servers``, each share its own ``wrk`` run at
    once; requests/s added, latencies of the slowest."""
    share = connections // len(servers)
    results: list[dict[str, float]] = [{} for _ in servers]

    def run(i: int) -> None:
        results[i] = wrk(servers[i].base, share, seconds, clips)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(servers))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=seconds + 120)
    return {
        "rps": sum(r["rps"] for r in results),
        "p50_ms": max(r["p50_ms"] for r in results),
        "p99_ms": max(r["p99_ms"] for r in results),
        "bad": sum(r["bad"] + r["errors"] for r in results),
        "requests": sum(r["requests"] for r in results),
    }


def report(label: str, result: dict[str, float]) -> None:
    print(
        f"{label:<28} {result['rps']:7.0f} requests/s, median {result['p50_ms']:.2f} ms, "
        f"p99 {result['p99_ms']:.2f} ms, {int(result['requests'])} requests, "
        f"{int(result['bad'])} bad answers or errors"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=100_000)
    parser.add_argument("--duration", type=int, default=15, help="seconds per wrk run")
    parser.add_argument("--rebuild-at", type=int, default=0, help="only time a rebuild at N")
    parser.add_argument(
        "--skip-load", action="store_true", help="only time a fresh replica (no SQLite library)"
    )
    args = parser.parse_args()
    binaries = bin_dir()
    if binaries is None:
        print("PostgreSQL 15 is not installed (apt-get install -y postgresql-15)", file=sys.stderr)
        return 2
    print(f"machine: {machine()}")
    work = Path(tempfile.mkdtemp(prefix="mocap-bench-replicas-"))
    user = "postgres" if os.geteuid() == 0 else None
    pg_root = Path(tempfile.mkdtemp(prefix="mocap-bench-pg-"))
    if user:
        entry = pwd.getpwnam(user)
        os.chown(pg_root, entry.pw_uid, entry.pw_gid)
    cluster = Cluster(binaries, pg_root, user=user)
    cluster.start()
    servers: list[Server] = []
    try:
        url = cluster.new_database()
        print(f"PostgreSQL 15 at {url} (fsync off: a benchmark database)")
        if args.rebuild_at:
            time_rebuild(url, args.rebuild_at, work)
            return 0
        if not args.skip_load:
            seconds = fill(args.count, work / "sqlite", None)
            print(f"SQLite library filled to {args.count} clips in {seconds:.0f} s")
        seconds = fill(args.count, work / "filler", url)
        print(f"PostgreSQL library filled to {args.count} clips in {seconds:.0f} s")
        pg = {"MOCAP_DATABASE_URL": url}
        log = work / "servers.log"

        fresh = []
        for n in range(3):  # a new replica each time: no index files, all rebuilt
            server = Server(work / f"fresh-{n}", log, **pg)
            fresh.append(server.startup)
            server.stop()
        restarted = Server(work / "fresh-2", log, **pg)
        restart = restarted.startup
        restarted.stop()
        print(
            f"fresh replica ready (indexes rebuilt from PostgreSQL, {args.count} clips): "
            f"{', '.join(f'{s:.2f}' for s in fresh)} s (median {statistics.median(fresh):.2f}); "
            f"restarted with its index files: {restart:.2f} s"
        )
        if args.skip_load:
            return 0

        clips = args.count
        configurations = [
            ("1 replica, SQLite", [(work / "sqlite", {})]),
            ("1 replica, PostgreSQL", [(work / "replica-a", pg)]),
            ("2 replicas, PostgreSQL", [(work / "replica-a", pg), (work / "replica-b", pg)]),
        ]
        for label, replicas in configurations:
            servers = [Server(data_dir, log, **settings) for data_dir, settings in replicas]
            load(servers, 32, 5, clips)  # warm-up
            print(f"load average before: {os.getloadavg()[0]:.2f}")
            report(label + ", 32 conns", load(servers, 32, args.duration, clips))
            for server in servers:
                server.stop()
            servers = []
        print(f"load average after: {os.getloadavg()[0]:.2f}")
    finally:
        for server in servers:
            server.stop()
        cluster.stop()
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
