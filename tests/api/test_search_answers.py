"""Search answers byte for byte: a fixed library, a fixed list of requests, and the answers the
service gave before search moved from SQL to the in-memory catalogue (issue 23), recorded in
``tests/fixtures/search-answers.json`` (recorded again by main's SQL code when issue 24 added
licence filters, ``collapse`` and ``similarity``). Any change to what a search returns — a
hit, a distance's last digit, a field's order, a label's spelling, an error's wording — shows
here.

The library is written row by row with integer-valued vectors: every distance is then the
square root of an exact integer sum whatever the order FAISS or BLAS add in, so the recorded
bytes hold on any CPU. Regenerate (only when an answer is meant to change) with
``.venv/bin/python -m tests.api.test_search_answers``.
"""

from __future__ import annotations

import json
import sys
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from app.config import Settings
from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.db import windows as window_db
from app.main import create_app
from app.motion.windows import window_spans
from app.services.describe import WINDOW_DESCRIPTORS, WINDOW_LENGTHS
from app.services.library import open_library

GOLDEN = Path(__file__).resolve().parents[1] / "fixtures" / "search-answers.json"
CLIPS = 40
FRAME_TIME = 1 / 30
NAMES = ['café "quoted" \\ back', "走る", "a/b <c> & d", "plain"]
LABELS = ["walk", "happy", "Run", "jump", "Sad"]
FORMATS = [("bvh", ("take.bvh",)), ("asf/amc", ("subject.asf", "take.amc")), ("fbx", ("a.fbx",))]


def build_library(settings: Settings) -> None:
    """Write the fixed library (ids 1..CLIPS in a fresh database)."""
    rng = np.random.default_rng(2023)
    library = open_library(settings)
    try:
        clips = []
        for number in range(1, CLIPS + 1):
            frames = int(rng.integers(40, 400))
            fmt, files = FORMATS[number % len(FORMATS)]
            labels = tuple(
                LABELS[i] for i in sorted(rng.choice(len(LABELS), rng.integers(0, 3), False))
            )
            windows = []
            spans = window_spans(frames, FRAME_TIME, WINDOW_LENGTHS)
            for name in WINDOW_DESCRIPTORS:
                info = library.descriptors[name]
                windows.append(
                    window_db.NewWindows(
                        name=name,
                        version=info.version,
                        lengths=np.asarray(WINDOW_LENGTHS, np.float64)[spans[:, 0]],
                        starts=spans[:, 1],
                        stops=spans[:, 2],
                        vectors=rng.integers(-8, 9, (len(spans), info.dimension)).astype(
                            np.float32
                        ),
                    )
                )
            clips.append(
                clip_db.NewClip(
                    name=f"{NAMES[number % len(NAMES)]} {number}",
                    format=fmt,
                    content_hash=f"{number:064x}",
                    frame_count=frames,
                    frame_time=FRAME_TIME,
                    duration=frames * FRAME_TIME,
                    joint_count=20 + number % 5,
                    skeleton_family=("bandai", "cmu", "mixamo")[number % 3],
                    lead_in_frames=0,
                    labels=labels,
                    # Odd clips have no stored file: a moments search from one reads its
                    # stored windows (the others' files are not written, so not readable).
                    files=()
                    if number % 2
                    else tuple(
                        clip_db.FileRecord(
                            "file" if len(files) == 1 else role, f"{number}-{name}", "0" * 64, 1
                        )
                        for role, name in zip(("skeleton", "motion"), files, strict=False)
                    ),
                    vectors={
                        name: vector_db.StoredVector(
                            info.version,
                            rng.integers(-8, 9, info.dimension).astype(np.float32),
                        )
                        for name, info in library.descriptors.items()
                    },
                    created_at=datetime(2024, 5, 6, 7, 8, number, tzinfo=UTC),
                    source=None if number % 4 else f"studio {number % 3}",
                    licence=None if number % 5 else "CC BY 4.0",
                    warnings=("a warning",) if number % 7 == 0 else (),
                    windows=tuple(windows),
                )
            )
        with library.writes.begin() as session:
            clip_db.insert_clips(session, clips)
    finally:
        library.close()


def requests() -> list[str]:
    """The requests whose answers are compared."""
    paths = [f"/search?clip={clip}&k=5" for clip in range(1, CLIPS + 1)]
    paths += [f"/search?clip={clip}&k=3&descriptor=posture" for clip in (1, 7, 22)]
    paths += [f"/search?clip={clip}&k=50&descriptor=kinetic" for clip in (2, 40)]
    paths += [
        "/search?clip=3&k=10&label=walk",
        "/search?clip=3&k=10&label=WALK&label=happy",
        "/search?clip=3&k=10&label=run,sad",
        "/search?clip=3&k=10&label=nobody",
        "/search?clip=3&k=10&label=",
        "/search?clip=999&k=5",
        "/search?clip=3&k=0",
        "/search?clip=3&descriptor=bogus",
        "/search?clip=x",
        "/search?clip=3&k=10&licence=CC BY 4.0",
        "/search?clip=3&k=10&licence=!cc by 4.0",
        "/search?clip=3&k=10&licence=CC BY 4.0&label=walk",
        "/search?clip=3&k=10&licence=nobody's",
        "/search?clip=3&k=10&collapse=capture",
        "/search?clip=18&k=4&descriptor=posture&collapse=capture&licence=!CC BY 4.0",
    ]
    paths += [f"/search/moments?clip={clip}" for clip in (1, 5, 11, 31)]
    paths += [
        "/search/moments?clip=3&k=5&per_clip=1",
        "/search/moments?clip=3&k=20&label=walk",
        "/search/moments?clip=9&start=0&end=1",
        "/search/moments?clip=9&start=0.1&end=2.3",
        "/search/moments?clip=999",
        "/search/moments?clip=9&descriptor=posture",
        "/search/moments?clip=3&k=8&licence=CC BY 4.0",
        "/search/moments?clip=3&k=8&licence=!CC BY 4.0&label=happy",
        "/search/moments?clip=7&k=5&collapse=capture",
    ]
    return paths


def answers(settings: Settings) -> list[dict[str, object]]:
    build_library(settings)
    with TestClient(create_app(settings)) as client:
        found = []
        for path in requests():
            response = client.get(path)
            found.append({"request": path, "status": response.status_code, "body": response.text})
    return found


def test_search_answers_are_byte_identical(tmp_path: Path) -> None:
    recorded = json.loads(GOLDEN.read_text())
    got = answers(Settings(data_dir=tmp_path / "data"))
    assert [a["request"] for a in got] == [a["request"] for a in recorded]
    for mine, theirs in zip(got, recorded, strict=True):
        assert (mine["status"], mine["body"]) == (theirs["status"], theirs["body"]), mine["request"]


def test_clip_lists_of_8_bit_codes_answer_the_same_bytes(tmp_path: Path) -> None:
    # MOCAP_CLIP_CODES=sq8 on IVF clip indexes (every cell scanned): the candidates re-ranked
    # by their exact vectors answer the recorded searches, distances to the last digit.
    recorded = json.loads(GOLDEN.read_text())
    settings = Settings(
        data_dir=tmp_path / "data", index_type="ivf", ivf_nprobe=1_000, clip_codes="sq8"
    )
    got = answers(settings)
    for name in ("motion", "posture", "kinetic"):  # the lists were codes
        assert json.loads((settings.index_dir / f"{name}.json").read_text())["codes"] == "sq8"
    for mine, theirs in zip(got, recorded, strict=True):
        if not str(mine["request"]).startswith("/search?"):
            continue  # moments: window indexes, their own setting
        assert (mine["status"], mine["body"]) == (theirs["status"], theirs["body"]), mine["request"]


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        result = answers(Settings(data_dir=Path(scratch) / "data"))
    GOLDEN.write_text(json.dumps(result, indent=1, ensure_ascii=False) + "\n")
    print(f"wrote {len(result)} answers to {GOLDEN}", file=sys.stderr)
