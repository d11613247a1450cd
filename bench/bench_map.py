"""``GET /map`` of a 100,000-clip library (issue 21).

Run from the repository root::

    .venv/bin/python bench/bench_map.py [--clips 100000] [--data-dir DIR]

The library (cached in ``DIR``, default ``$TMPDIR/mocap-bench-map-<clips>``): Bandai dataset
1 imported, then ``mocap-index fill-synthetic`` clips up to ``--clips`` (no moment windows:
the map does not read them). Then:

1. in this process, the layout of the ``motion`` vectors (the slow part of the map): the
   nearest neighbours from the random-projection forest plus the PCA on a sample, against
   the exact all-pairs isolation of the code before (timed on 10,000 clips and scaled by
   the square of the count: it is O(N^2); all of them would take minutes);
2. a real server: the first ``GET /map`` (computed, while 8 more requests wait for the same
   computation), a second one (nothing changed: the same answer), then an upload and 8
   requests at once (answered with the last layout while the new one is computed in the
   background), and how long until the new clip is placed.

Wall times and CPU seconds (``time.process_time``) are printed with the load average: on the
shared 2-core machines only the ratio means much.
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np
from bench_search import CLI, Server, environment
from common import machine, shared_data  # bench/common.py (scripts run from bench/)

from app.config import Settings
from app.db import vectors as vector_db
from app.services import library_map, map_geometry
from app.services.library import open_library

# No windows (the map does not read them); the 8-9 requests at once come from one address, so
# the per-client share of heavy requests is lifted (else most of them get 429).
NO_MOMENTS = {"MOCAP_MOMENTS": "false", "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "64"}
SAMPLE = 10_000
DESCRIPTOR = "motion"


def ensure_library(data_dir: Path, clips: int) -> None:
    database = data_dir / "mocap-index.sqlite3"
    if not database.exists():
        source = str(shared_data() / "bandai-ds1")
        command = [CLI, "import", "--no-progress", "--data-dir", str(data_dir), source]
        subprocess.run(command, check=True, env=environment(**NO_MOMENTS))
    with sqlite3.connect(database) as db:
        held = db.execute("SELECT count(*) FROM clips").fetchone()[0]
    if held < clips:
        command = [CLI, "fill-synthetic", "--count", str(clips), "--data-dir", str(data_dir)]
        subprocess.run(command, check=True, env=environment(**NO_MOMENTS))


def timed(what: str, work: object) -> tuple[object, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    result = work()  # type: ignore[operator]
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    print(f"  {what}: {wall:.1f} s wall, {cpu:.1f} s CPU")
    return result, wall, cpu


def in_process(data_dir: Path) -> tuple[float, float]:
    library = open_library(Settings(data_dir=data_dir, moments=False))
    try:
        info = library.descriptor(DESCRIPTOR)
        with library.reads() as session:
            _, vectors = vector_db.load_vectors(session, info.name, info.version, info.dimension)
    finally:
        library.close()
    n = len(vectors)
    print(f"layout of {n} {DESCRIPTOR} vectors ({vectors.shape[1]} numbers each):")
    _, _, new_cpu = timed(
        "forest neighbours + PCA on a sample", lambda: library_map.vector_layout(vectors)
    )
    rng = np.random.default_rng(0)
    sample = vectors[rng.choice(n, min(n, SAMPLE), replace=False)]
    limit = map_geometry.EXACT_NEIGHBOURS_UP_TO
    map_geometry.EXACT_NEIGHBOURS_UP_TO = n + 1  # the code before: all pairs, always
    try:
        _, _, old_cpu = timed(
            f"exact all-pairs isolation of {len(sample)} (the code before)",
            lambda: map_geometry.isolation_scores(sample),
        )
    finally:
        map_geometry.EXACT_NEIGHBOURS_UP_TO = limit
    scaled = old_cpu * (n / len(sample)) ** 2
    print(
        f"  the code before on all {n}: about {scaled:.0f} s CPU (x (N/{len(sample)})^2); "
        f"now {new_cpu:.1f} s: {scaled / new_cpu:.0f} times less"
    )
    return new_cpu, scaled


def at_once(base: str, count: int) -> list[float]:
    """``count`` GET /map at the same moment; each one's seconds."""
    times: list[float] = []
    start = threading.Barrier(count)

    def ask() -> None:
        start.wait()
        began = time.perf_counter()
        response = httpx.get(f"{base}/map", params={"descriptor": DESCRIPTOR}, timeout=900)
        response.raise_for_status()
        times.append(time.perf_counter() - began)

    threads = [threading.Thread(target=ask) for _ in range(count)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return sorted(times)


def live(data_dir: Path) -> None:
    log = data_dir.parent / "mocap-bench-map-server.log"
    server = Server(data_dir, log, **NO_MOMENTS)
    try:
        first = at_once(server.base, 9)
        print(f"server: 9 first GET /map at once: {first[0]:.1f}-{first[-1]:.1f} s (one layout)")
        began = time.perf_counter()
        body = httpx.get(f"{server.base}/map", params={"descriptor": DESCRIPTOR}, timeout=900)
        print(
            f"  again, nothing changed: {time.perf_counter() - began:.2f} s "
            f"({len(body.content) / 2**20:.0f} MB of JSON, {body.json()['count']} clips)"
        )
        upload = shared_data() / "bandai-ds1" / "data" / "dataset-1_walk_normal_001.bvh"
        data = upload.read_bytes() + f"\n{time.time()}\n".encode()  # new content each run
        added = httpx.post(f"{server.base}/clips", files={"file": ("new.bvh", data)}, timeout=60)
        added.raise_for_status()
        new_id = added.json()["id"]
        changed = time.perf_counter()
        after = at_once(server.base, 8)
        print(
            f"  after an upload, 8 GET /map at once: {after[0]:.1f}-{after[-1]:.1f} s "
            "(the last layout, the new one computed in the background)"
        )
        while True:
            clips = httpx.get(
                f"{server.base}/map", params={"descriptor": DESCRIPTOR}, timeout=900
            ).json()["clips"]
            if any(c["id"] == new_id and c["pca"] is not None for c in clips):
                break
            time.sleep(1)
        print(f"  the new clip placed {time.perf_counter() - changed:.0f} s after the upload")
        httpx.delete(f"{server.base}/clips/{new_id}", timeout=60)
    finally:
        server.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clips", type=int, default=100_000)
    parser.add_argument("--data-dir", type=Path)
    args = parser.parse_args()
    data_dir = args.data_dir or Path(tempfile.gettempdir()) / f"mocap-bench-map-{args.clips}"
    print(f"machine: {machine()}")
    ensure_library(data_dir, args.clips)
    in_process(data_dir)
    live(data_dir)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
