"""Where an import's CPU goes, per clip and stage, in one process (CPU time, not wall).

Run from the repository root::

    .venv/bin/python bench/bench_import_stages.py [--rounds 3]

Worker stages: what ``mocap-index import``'s worker processes do per clip (read the file,
sha256, parse — hierarchy, frame block, ``Motion`` —, body — skeleton mapping, forward
kinematics, the rest —, the three clip descriptors, windows), over the clips of
bandai-ds1 (POLARS_MAX_THREADS=1, as in the workers). Main-process stages: what
``store_many`` does per clip for batches of 64 of the same clips (new content each round)
on a new library: files, rows, index sync, the reads around them. The stages are timed by
wrapping the functions that do them (inclusive times; "other" is the rest).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import functools
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("POLARS_MAX_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import machine, shared_data  # bench/common.py (scripts run from bench/)

from app.config import Settings
from app.db import clips as clip_db
from app.motion import body as body_module
from app.motion import pipeline
from app.motion.descriptors import REGISTRY
from app.motion.formats import bvh
from app.motion.model import ParseLimits
from app.services.blobs import FileBlobStore
from app.services.describe import MotionDescriber
from app.services.ingest import Described, store_many
from app.services.library import Library, open_library
from app.services.uploads import Upload

SPENT: collections.Counter[str] = collections.Counter()


def timed(owner: Any, name: str, stage: str) -> None:
    """Count the CPU time of every call of ``owner.name`` under ``stage``."""
    function = getattr(owner, name)

    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        started = time.process_time()
        try:
            return function(*args, **kwargs)
        finally:
            SPENT[stage] += time.process_time() - started

    setattr(owner, name, wrapper)


def time_compute(name: str) -> None:
    descriptor = REGISTRY[name]
    compute: Callable[[Any], Any] = descriptor.compute

    def wrapper(body: Any) -> Any:
        started = time.process_time()
        try:
            return compute(body)
        finally:
            SPENT[f"analyse: {name} descriptor"] += time.process_time() - started

    object.__setattr__(descriptor, "compute", wrapper)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3, help="the first is a warm-up")
    args = parser.parse_args()
    files = sorted((shared_data() / "bandai-ds1").rglob("*.bvh"))
    print(f"machine: {machine()}")
    print(f"{len(files)} Bandai clips, {args.rounds - 1} timed rounds")

    for owner, name, stage in (
        (bvh._HIERARCHIES, "read", "parse: hierarchy (remembered per rig)"),
        (bvh, "read_frames", "parse: frame block"),
        (bvh, "_build_motion", "parse: Motion (Euler -> matrices)"),
        (body_module, "map_skeleton", "body: skeleton mapping"),
        (body_module, "forward_kinematics", "body: forward kinematics"),
        (pipeline, "build_body", "body (all)"),
        (MotionDescriber, "_windows", "windows"),
        (FileBlobStore, "put_many", "store: files (write, fsync, rename)"),
        (clip_db, "insert_clips", "store: rows (one transaction)"),
        (Library, "sync_indexes", "store: index sync (reads rows back)"),
        (clip_db, "get_clips", "store: clip records for the results"),
        (clip_db, "clip_ids_by_hash", "store: content-hash lookups"),
    ):
        timed(owner, name, stage)
    for name in REGISTRY:
        time_compute(name)
    describer = MotionDescriber()
    limits = ParseLimits()
    worker_total = 0.0
    described = []
    for round_number in range(args.rounds):
        if round_number == 1:
            SPENT.clear()
            worker_total = 0.0
        described = []
        for path in files:
            started = time.process_time()
            data = path.read_bytes()
            SPENT["read the file"] += time.process_time() - started
            upload = Upload.from_files(file=(path.name, data))
            mark = time.process_time()
            _ = upload.parts[0].sha256
            SPENT["sha256"] += time.process_time() - mark
            described.append(Described(upload, describer.describe(upload, limits)))
            worker_total += time.process_time() - started
    clips = len(files) * (args.rounds - 1)
    worker_stages = dict(SPENT)

    SPENT.clear()
    with tempfile.TemporaryDirectory(prefix="mocap-bench-stages-") as tmp:
        library = open_library(Settings(data_dir=Path(tmp) / "data"))
        for index in [*library.indexes.values(), *library.window_indexes.values()]:
            index.autosave = False
        main_total = 0.0
        stored = 0
        for round_number in range(args.rounds):
            for start in range(0, len(described), 64):
                batch = [_renamed(d, round_number) for d in described[start : start + 64]]
                started = time.process_time()
                store_many(library, batch)
                if round_number:
                    main_total += time.process_time() - started
                    stored += len(batch)
            if not round_number:
                SPENT.clear()
        library.close()

    print(f"\nworker process, per clip (CPU ms): {worker_total / clips * 1e3:.2f} in all")
    _table(worker_stages, clips)
    print(f"\nmain process store_many, per clip (CPU ms): {main_total / stored * 1e3:.2f} in all")
    _table(dict(SPENT), stored)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


def _renamed(item: Described, copy: int) -> Described:
    """``item`` as new content: its file with ``copy`` + 1 more newlines."""
    parts = tuple(
        dataclasses.replace(part, data=part.data + b"\n" * (copy + 1)) for part in item.upload.parts
    )
    return Described(dataclasses.replace(item.upload, parts=parts), item.description)


def _table(stages: dict[str, float], clips: int) -> None:
    for stage, seconds in sorted(stages.items()):
        print(f"  {stage:40s} {seconds / clips * 1e3:6.2f} ms")


if __name__ == "__main__":
    sys.exit(main())
