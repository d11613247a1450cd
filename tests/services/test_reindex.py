"""``mocap-index reindex`` recomputes every clip from its own stored upload: a clip of a
multi-animation FBX/glTF file is described again from *its* animation, not the file's
longest one (which gave every shorter animation's clip the longest one's vectors, windows,
frame count and duration).

Each animation of the file is uploaded as its own clip over HTTP, everything the motion core
measured is read from the database, the real command runs (``reindex --all``), and every
vector, window, frame count and duration must come back exactly as they were.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from app.cli import main
from app.config import Settings
from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.db import windows as window_db
from app.main import create_app
from app.motion.formats import read_bvh
from app.services.library import open_library
from tests.conftest import FIXTURES_DIR, SharedData
from tests.motion.gltf_builder import multi_animation_glb

REAL_MULTI_ANIMATION = Path("wild-more") / "threejs-examples" / "danielrmz18_Xbot.glb"


def measured(settings: Settings, clip_ids: list[int]) -> dict[int, dict[str, Any]]:
    """Everything the motion core wrote about each clip: its fields, vectors and windows."""
    library = open_library(settings)
    try:
        with library.reads() as session:
            result = {}
            for clip_id in clip_ids:
                clip = clip_db.get_clip(session, clip_id)
                assert clip is not None
                windows = {
                    name: window_db.load_window_rows(session, key, [clip_id]).get(clip_id)
                    for name, key in library.window_keys.items()
                }
                result[clip_id] = {
                    "frame_count": clip.frame_count,
                    "frame_time": clip.frame_time,
                    "duration": clip.duration,
                    "lead_in_frames": clip.lead_in_frames,
                    "joint_count": clip.joint_count,
                    "vectors": vector_db.get_vectors(session, clip_id),
                    "windows": windows,
                }
    finally:
        library.close()
    return result


def assert_same(before: dict[str, Any], after: dict[str, Any], what: str) -> None:
    for field in ("frame_count", "frame_time", "duration", "lead_in_frames", "joint_count"):
        assert after[field] == before[field], (what, field)
    assert after["vectors"].keys() == before["vectors"].keys(), what
    for name, stored in before["vectors"].items():
        np.testing.assert_array_equal(after["vectors"][name].vector, stored.vector, err_msg=what)
    assert after["windows"].keys() == before["windows"].keys(), what
    for name, rows in before["windows"].items():
        if rows is None:  # too short for windows of that length
            assert after["windows"][name] is None, (what, name)
            continue
        for old, new in zip(rows, after["windows"][name], strict=True):
            np.testing.assert_array_equal(new, old, err_msg=f"{what}: {name}")


def upload_every_animation(
    settings: Settings, filename: str, data: bytes
) -> dict[str, dict[str, Any]]:
    """Each animation of the file stored as its own clip: name -> the clip as the API shows it
    (animations the service refuses, too short say, are left out)."""
    clips: dict[str, dict[str, Any]] = {}
    with TestClient(create_app(settings)) as client:
        first = client.post("/clips", files={"file": (filename, data)})
        assert first.status_code == 201, first.text
        names = [a["name"] for a in first.json()["animations"]]
        for name in names:
            answer = client.post(
                "/clips", files={"file": (filename, data)}, data={"animation": name}
            )
            if answer.status_code == 422:
                continue
            assert answer.status_code in (200, 201), answer.text
            clips[name] = answer.json()
    return clips


def check_reindex_keeps_every_animation(settings: Settings, filename: str, data: bytes) -> None:
    clips = upload_every_animation(settings, filename, data)
    assert len(clips) >= 3, clips.keys()
    frame_counts = {clip["frame_count"] for clip in clips.values()}
    assert len(frame_counts) >= 2, "the animations must differ in length for the test to bite"
    ids = [clip["id"] for clip in clips.values()]
    before = measured(settings, ids)

    code = main(["reindex", "--all", "--no-progress", "--data-dir", str(settings.data_dir)])
    assert code == 0

    after = measured(settings, ids)
    for name, clip in clips.items():
        assert_same(before[clip["id"]], after[clip["id"]], f"animation {name!r}")


def test_reindex_keeps_each_animation_of_a_built_file(settings: Settings) -> None:
    walk = read_bvh((FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes())
    # Ten seconds of the real walk played back and forth: every window length has windows.
    there_and_back = np.r_[np.arange(1, 41), np.arange(39, 0, -1)]
    frames = np.r_[np.tile(there_and_back, 15), 1][:1201]
    motion = dataclasses.replace(
        walk,
        root_translation=walk.root_translation[frames],
        local_rotations=walk.local_rotations[frames],
    )
    glb = multi_animation_glb(
        {
            "all": motion,
            "start": motion.slice_frames(0, 500),
            "middle": motion.slice_frames(300, 1000),
        }
    )
    check_reindex_keeps_every_animation(settings, "three.glb", glb)


def test_reindex_keeps_each_animation_of_a_real_file(
    settings: Settings, shared_data: SharedData
) -> None:
    path = shared_data(*REAL_MULTI_ANIMATION.parts)
    check_reindex_keeps_every_animation(settings, path.name, path.read_bytes())
