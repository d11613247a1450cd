"""Moments answers to the last digit: a fixed library, a fixed list of queries, and the
answers the search gave before its bookkeeping was made cheaper (issue 23), recorded in
``tests/fixtures/moments-answers.json``. The moments list is exact (issue 24): a faster
search must find the very same moments, in the same order, at the same distances — a
moment, a placement's last digit or a similarity that changes shows here.

The library is written row by row with integer-valued window vectors (each clip a random
walk, so neighbouring windows are alike and moments have a shape; some clips copy a stretch
of another, so exact copies and ties occur): every pair's distance is then the square root
of an exact integer sum whatever order BLAS adds in, and the recorded answers hold on any
CPU. Queries are stored clips without files (their parts are their stored windows), whole
or cut to spans of every part length, with ``k``, ``per_clip``, label and ``collapse``
variations.

A second test searches the same library through IVF window indexes that probe every cell
(``MOCAP_IVF_NPROBE``): the mapped lists (app/index/frozen.py) must give the flat indexes'
answers exactly.

Regenerate (only when an answer is meant to change) with
``.venv/bin/python -m tests.services.test_moments_answers``.
"""

from __future__ import annotations

import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.config import Settings
from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.db import windows as window_db
from app.errors import MocapError
from app.motion.windows import window_spans
from app.services.describe import WINDOW_DESCRIPTORS, WINDOW_LENGTHS
from app.services.library import Library, open_library
from app.services.moments import search_moments_by_clip

GOLDEN = Path(__file__).resolve().parents[1] / "fixtures" / "moments-answers.json"
CLIPS = 240
FRAME_TIMES = (1 / 30, 1 / 24, 1 / 60)
LABELS = ("walk", "run", "jump")


def _walk(rng: np.random.Generator, count: int, dimension: int) -> np.ndarray:
    """``(count, dimension)`` integer-valued float32 rows, each a small step from the last,
    from near one of a few starts (clips alike: a search must look at many)."""
    start = np.random.default_rng(int(rng.integers(4))).integers(-20, 21, dimension)
    start += rng.integers(-2, 3, dimension)
    steps = rng.integers(-2, 3, (count, dimension))
    steps[0] = 0
    return (start + np.cumsum(steps, axis=0)).astype(np.float32)


def build_library(settings: Settings) -> None:
    """Write the fixed library (ids 1..CLIPS in a fresh database)."""
    rng = np.random.default_rng(2024)
    library = open_library(settings)
    try:
        clips = []
        earlier: list[dict[str, np.ndarray]] = []  # each clip's windows, by descriptor
        for number in range(1, CLIPS + 1):
            frame_time = FRAME_TIMES[number % len(FRAME_TIMES)]
            frames = int(rng.integers(round(0.8 / frame_time), round(14 / frame_time)))
            spans = window_spans(frames, frame_time, WINDOW_LENGTHS)
            windows, held = [], {}
            for name in WINDOW_DESCRIPTORS:
                info = library.descriptors[name]
                vectors = _walk(rng, len(spans), info.dimension)
                if number % 9 == 0 and earlier:  # a stretch copied from an earlier clip
                    source = earlier[int(rng.integers(len(earlier)))][name]
                    size = min(len(source), len(vectors))
                    vectors[:size] = source[:size]
                held[name] = vectors
                windows.append(
                    window_db.NewWindows(
                        name=name,
                        version=info.version,
                        lengths=np.asarray(WINDOW_LENGTHS, np.float64)[spans[:, 0]],
                        starts=spans[:, 1],
                        stops=spans[:, 2],
                        vectors=vectors,
                    )
                )
            earlier.append(held)
            labels = tuple(
                LABELS[i] for i in sorted(rng.choice(len(LABELS), rng.integers(0, 3), False))
            )
            clips.append(
                clip_db.NewClip(
                    name=f"clip {number}",
                    format="bvh",
                    content_hash=f"{number:064x}",
                    frame_count=frames,
                    frame_time=frame_time,
                    duration=frames * frame_time,
                    joint_count=20,
                    skeleton_family="bandai",
                    lead_in_frames=0,
                    labels=labels,
                    files=(),  # no file: a query's parts are its stored windows
                    vectors={
                        name: vector_db.StoredVector(
                            info.version,
                            rng.integers(-8, 9, info.dimension).astype(np.float32),
                        )
                        for name, info in library.descriptors.items()
                    },
                    created_at=datetime(2024, 5, 6, 7, 8, number % 60, tzinfo=UTC),
                    windows=tuple(windows),
                )
            )
        with library.writes.begin() as session:
            clip_db.insert_clips(session, clips)
    finally:
        library.close()


def queries() -> list[dict[str, Any]]:
    """The queries whose answers are compared (keyword arguments of the search)."""
    found: list[dict[str, Any]] = []
    for clip in range(1, CLIPS + 1, 7):  # whole clips
        found.append({"clip_id": clip, "k": 10, "per_clip": 1})
    for clip, start, end in [
        (4, 0.0, 1.0),  # no parts: the span's vector is a stored window's
        (5, 0.25, 1.5),  # 1-s parts
        (9, 0.5, 3.5),  # 2-s parts
        (14, 0.0, 5.5),
        (27, 1.0, 8.0),  # 4-s parts
        (50, 0.5, 13.5),  # 8-s parts
        (45, 2.0, 4.0),
        (63, 0.0, 2.0),
        (72, 0.1, 1.3),
    ]:
        found.append({"clip_id": clip, "start": start, "end": end, "k": 10, "per_clip": 1})
    found += [
        {"clip_id": 10, "k": 50, "per_clip": 3},
        {"clip_id": 11, "k": 1, "per_clip": 1},
        {"clip_id": 12, "k": 30, "per_clip": 10},
        {"clip_id": 13, "k": 20, "per_clip": 2, "label": ["walk"]},
        {"clip_id": 14, "k": 20, "per_clip": 1, "label": ["run", "jump"]},
        {"clip_id": 18, "k": 15, "per_clip": 1, "collapse": True},
        {"clip_id": 27, "k": 100, "per_clip": 100},
    ]
    return found


def answers(library: Library) -> list[dict[str, Any]]:
    """Every query's moments: clip, span, distance (exact, as hex) and similarity."""
    found = []
    for query in queries():
        given = {"start": None, "end": None, "label": None, **query}
        try:
            _, moments = search_moments_by_clip(library, descriptor="motion", **given)
        except MocapError as error:
            found.append({"query": query, "error": [error.code, error.detail]})
            continue
        found.append(
            {
                "query": query,
                "moments": [
                    [m.clip.id, m.start, m.end, m.distance.hex(), m.similarity]
                    + [[o.clip.id, o.start, o.end, o.distance.hex()] for o in m.others]
                    for m in moments
                ],
            }
        )
    return found


def answers_of(settings: Settings) -> list[dict[str, Any]]:
    build_library(settings)
    library = open_library(settings)
    try:
        return answers(library)
    finally:
        library.close()


def test_moments_answers_are_identical(tmp_path: Path) -> None:
    recorded = json.loads(GOLDEN.read_text())
    got = answers_of(Settings(data_dir=tmp_path / "data"))
    assert [a["query"] for a in got] == [a["query"] for a in recorded]
    for mine, theirs in zip(got, recorded, strict=True):
        assert mine == theirs, mine["query"]


@pytest.mark.parametrize("codes", ["float32", "sq8"])
def test_ivf_window_indexes_probing_every_cell_give_the_same_answers(
    tmp_path: Path, codes: str
) -> None:
    recorded = json.loads(GOLDEN.read_text())
    settings = Settings(
        data_dir=tmp_path / "data", index_type="ivf", ivf_nprobe=1 << 20, window_codes=codes
    )
    build_library(settings)
    library = open_library(settings)
    try:
        assert {index.kind for index in library.window_indexes.values()} == {"ivf"}
        assert all(index.mapped for index in library.window_indexes.values())
        got = answers(library)
    finally:
        library.close()
    for mine, theirs in zip(got, recorded, strict=True):
        assert mine == theirs, mine["query"]


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        result = answers_of(Settings(data_dir=Path(scratch) / "data"))
    GOLDEN.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {len(result)} answers to {GOLDEN}", file=sys.stderr)
