"""Label filters at a million clips: case-insensitive, all-of, still index lookups.

Run from the repository root::

    .venv/bin/python bench/bench_labels.py [--count 1000000]

Builds a migrated SQLite database in a temporary directory with ``--count`` clips (rows only:
no files, no vectors), every clip labelled ``Synthetic`` (mixed case, as stored), one in ten
``walk``, one in a thousand ``Happy``; then times, over the service's own read paths:

* ``GET /search``'s filter: the ids carrying ``synthetic`` / ``walk,happy``, from the
  in-memory catalogue (:meth:`app.index.catalogue.Catalogue.ids_with_labels`; built here
  from the rows first);
* ``GET /clips?label=...``'s page and count (:func:`app.db.clips.list_clips`).

Target: a filter on a rare label in well under a millisecond's worth of rows scanned — the
(label_key, clip_id) index, never a table scan (checked with EXPLAIN QUERY PLAN).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from common import machine  # bench/common.py (scripts run from bench/)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sqlalchemy.orm import Session  # noqa: E402

from app.db import clips as clip_db  # noqa: E402
from app.db.entries import clip_entries  # noqa: E402
from app.db.migrate import upgrade  # noqa: E402
from app.db.session import create_db_engine  # noqa: E402
from app.index.catalogue import Catalogue  # noqa: E402


def fill(path: Path, count: int) -> None:
    import sqlite3

    db = sqlite3.connect(path)
    with db:
        db.executemany(
            "INSERT INTO clips (id, name, format, content_hash, frame_count, frame_time, "
            "duration, joint_count, skeleton_family, lead_in_frames, created_at) "
            "VALUES (?, ?, 'synthetic', ?, 1, 0.1, 0.1, 0, 'synthetic', 0, '2026-01-01')",
            ((i, f"synthetic-{i}", f"{i:064x}") for i in range(1, count + 1)),
        )
        rows = []
        for i in range(1, count + 1):
            rows.append((i, "Synthetic", "synthetic", 0))
            if i % 10 == 0:
                rows.append((i, "walk", "walk", 1))
            if i % 1000 == 0:
                rows.append((i, "Happy", "happy", 2))
        db.executemany(
            "INSERT INTO clip_labels (clip_id, label, label_key, position) VALUES (?, ?, ?, ?)",
            rows,
        )
    db.execute("ANALYZE")
    db.close()


def timed(fn, repeat: int = 20) -> tuple[float, object]:  # type: ignore[no-untyped-def]
    times = []
    result = None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=1_000_000)
    args = parser.parse_args()
    print(machine())
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "labels.sqlite3"
        engine = create_db_engine(f"sqlite:///{path}")
        upgrade(engine)
        start = time.perf_counter()
        fill(path, args.count)
        print(f"{args.count:,} clips filled in {time.perf_counter() - start:.1f} s")
        with Session(engine) as session:
            started = time.perf_counter()
            catalogue = Catalogue(Path(tmp) / "indexes")
            catalogue.replace_all(clip_entries(session), synced_to=0, persist=False)
            print(f"catalogue built in {time.perf_counter() - started:.1f} s")
        for label in ("HAPPY", "walk,Happy", "synthetic"):
            ms, ids = timed(lambda label=label: catalogue.ids_with_labels(label))
            print(f"search filter label={label!r}: {len(ids):,} ids in {ms:.2f} ms (median)")  # type: ignore[arg-type]
        with Session(engine) as session:
            for label in ("happy", "WALK,happy"):
                ms, (page, total) = timed(  # type: ignore[misc]
                    lambda label=label: clip_db.list_clips(session, label=label, limit=50, offset=0)
                )
                print(
                    f"GET /clips?label={label}: page of {len(page)}, total {total:,} in {ms:.2f} ms"
                )
            plan = (
                session.connection()
                .exec_driver_sql(
                    "EXPLAIN QUERY PLAN SELECT clip_id FROM clip_labels WHERE label_key = 'happy'"
                )
                .all()
            )
            print("plan:", "; ".join(str(row[-1]) for row in plan))
        engine.dispose()


if __name__ == "__main__":
    main()
