"""Hostile rigs and huge exports: rig uploads get the limits and isolation of clip uploads
(fuzzed files never answer 5xx), and an export's size is bounded before it is computed."""

from __future__ import annotations

import random
import resource
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.motion.formats import read_bvh
from app.motion.formats.bvh_writer import write_bvh
from app.motion.model import Motion
from tests.api.exporting import BVH, FBX, GLB, VRMA
from tests.hostile.test_hostile_uploads import SMALL

SEEDS = range(12)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(
        data_dir=tmp_path_factory.mktemp("hostile-rigs") / "data",
        parser_workers=1,
        max_frame_values=3_000_000,
    )
    with TestClient(create_app(settings)) as client:
        yield client


def check_answer(response, what: str) -> None:
    assert response.status_code < 500, (what, response.status_code, response.text)
    if response.status_code >= 400:
        body = response.json()
        assert set(body) == {"error", "detail"}, (what, body)


@pytest.mark.parametrize("case", [c for c in SMALL if len(c.parts) == 1], ids=lambda c: c.name)
def test_a_hostile_clip_file_as_a_rig_is_refused_cleanly(live, case) -> None:
    ((filename, data),) = case.parts.values()
    started = time.monotonic()
    response = live.post("/rigs", files={"file": (filename, data)})
    assert time.monotonic() - started < 10.0
    check_answer(response, case.name)


def mutate(data: bytes, seed: int) -> bytes:
    """Bytes flipped, a block cut out or the file cut short (one of them, by ``seed``)."""
    rng = random.Random(seed)
    out = bytearray(data)
    kind = seed % 3
    if kind == 0:
        for _ in range(rng.randint(1, 40)):
            out[rng.randrange(len(out))] = rng.randrange(256)
    elif kind == 1:
        start = rng.randrange(len(out))
        del out[start : start + rng.randint(1, 4096)]
    else:
        del out[rng.randrange(1, len(out)) :]
    return bytes(out)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("original", [BVH, FBX, GLB, VRMA], ids=["bvh", "fbx", "glb", "vrma"])
def test_a_fuzzed_rig_file_never_answers_5xx(live, original, seed) -> None:
    filename, data = original
    response = live.post("/rigs", files={"file": (filename, mutate(data, seed))})
    check_answer(response, f"{filename} #{seed}")


def test_the_service_stays_healthy(live) -> None:
    assert live.get("/health").json()["status"] == "ok"
    assert live.post("/rigs", files={"file": BVH}).status_code == 201


def long_bvh(frames: int) -> bytes:
    """The fixture walk repeated to ``frames`` frames."""
    walk = read_bvh(BVH[1]).slice_frames(1)
    reps = -(-frames // walk.frame_count)
    step = walk.root_translation[-1] - walk.root_translation[0]
    root = np.concatenate([walk.root_translation + i * step for i in range(reps)])[:frames]
    rotations = np.concatenate([walk.local_rotations] * reps)[:frames]
    return write_bvh(Motion(walk.skeleton, walk.frame_time, root, rotations)).encode()


def test_a_huge_export_is_bounded(live, tmp_path: Path) -> None:
    # 8,000 frames of 38 joints: near the 3,000,000-value limit of this service.
    clip = live.post("/clips", files={"file": ("long.bvh", long_bvh(8000))})
    assert clip.status_code == 201, clip.text
    clip_id = clip.json()["id"]
    started = time.monotonic()
    refused = live.get(f"/clips/{clip_id}/file?format=glb&fps=1000")
    assert refused.status_code == 422
    assert refused.json()["error"] == "limit_exceeded"
    assert "MOCAP_MAX_FRAME_VALUES" in refused.json()["detail"]
    assert time.monotonic() - started < 2.0  # refused before any work
    rig = live.post("/rigs", files={"file": BVH}).json()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    started = time.monotonic()
    done = live.get(f"/clips/{clip_id}/file?format=glb&rig={rig['id']}&root=extract&fps=60")
    took = time.monotonic() - started
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert done.status_code == 200, done.text
    assert took < 60.0, took
    assert grown_mb < 1024, grown_mb
