"""Stored previews are written when a clip is stored, from the body the describer built: the
same arrays a page would otherwise make by parsing the clip again, and never a reason for
storing the clip to fail. Real files, a real SQLite library, the real motion core."""

from __future__ import annotations

import logging
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.config import Settings
from app.db import clips as clip_db
from app.services import previews
from app.services.ingest import ingest
from app.services.library import Library, open_library
from app.services.preview_store import PREVIEWS_DIR
from app.services.reindex import reindex
from app.services.uploads import Upload
from tests.conftest import FIXTURES_DIR

CMU_BVH = "cmu_mb_02_01_first41.bvh"  # 120 fps with a lead-in frame: resampled to 30 fps
BANDAI = "bandai_walk_normal_001_first40.bvh"  # 30 fps: stored at its own rate
CMU_ASF, CMU_AMC = "cmu_02.asf", "cmu_02_01_first40.amc"
FBX = "ufbx_maya_human_ik_7400_binary.fbx"  # read in a parser worker process


@pytest.fixture
def library(settings: Settings) -> Iterator[Library]:
    library = open_library(settings)
    yield library
    library.close()


def stored_file(library: Library, clip: clip_db.ClipRecord) -> Path:
    version = previews.preview_version(library)
    return previews.preview_store(library.settings).path(clip.content_hash, version)


def made_on_demand(library: Library, clip: clip_db.ClipRecord) -> previews.DisplayMotion:
    """What a page would make of the clip without a stored preview: its file parsed again."""
    motion = previews.read_stored_motion(library, clip)
    return previews.at_store_rate(previews.display_motion(motion))


def assert_same(stored: previews.DisplayMotion | None, made: previews.DisplayMotion) -> None:
    assert stored is not None
    assert stored.positions.dtype == np.float32
    np.testing.assert_array_equal(stored.positions, made.positions)
    assert stored.frame_time == made.frame_time
    assert stored.lead_in_frames == made.lead_in_frames
    assert stored.source_frame_count == made.source_frame_count
    assert stored.source_frame_time == made.source_frame_time


def all_clips(library: Library) -> list[clip_db.ClipRecord]:
    with library.reads() as session:
        ids = clip_db.all_clip_ids(session)
        return list(clip_db.get_clips(session, ids).values())


@pytest.mark.parametrize("name", [CMU_BVH, BANDAI])
def test_a_stored_clip_comes_with_its_preview(library: Library, name: str) -> None:
    upload = Upload.from_files(file=(name, (FIXTURES_DIR / name).read_bytes()))
    clip = ingest(library, upload).clip
    path = stored_file(library, clip)
    assert path.is_file()
    store = previews.preview_store(library.settings)
    stored = store.load(clip.content_hash, previews.preview_version(library))
    assert_same(stored, made_on_demand(library, clip))
    assert stored is not None and stored.frame_time == pytest.approx(1 / 30, rel=1e-3)
    # Nothing half-written beside it.
    assert [p.name for p in path.parent.iterdir()] == [path.name]


def test_a_preview_that_cannot_be_written_does_not_fail_the_clip(
    library: Library, settings: Settings, caplog: pytest.LogCaptureFixture
) -> None:
    # A file where the folder should be: no preview can be written, whoever runs the tests
    # (file permissions do not stop root).
    (settings.data_dir / PREVIEWS_DIR).write_bytes(b"not a folder")
    upload = Upload.from_files(
        skeleton=(CMU_ASF, (FIXTURES_DIR / CMU_ASF).read_bytes()),
        motion=(CMU_AMC, (FIXTURES_DIR / CMU_AMC).read_bytes()),
    )
    with caplog.at_level(logging.WARNING, logger="app.services.previews"):
        result = ingest(library, upload)
    assert result.created and library.clip_count() == 1
    assert "cannot store the preview" in caplog.text
    assert not stored_file(library, result.clip).exists()
    # ...and the clip is previewed on demand, as before (the cache is not needed).
    cache = previews.SkeletonCache(settings.data_dir / PREVIEWS_DIR)
    shown = previews.stored_preview(library, cache, result.clip)
    assert_same(shown, made_on_demand(library, result.clip))


def test_import_stores_every_clips_preview(tmp_path: Path, settings: Settings) -> None:
    """``mocap-index import`` describes in worker processes (FBX read in a parser worker
    within them): the previews travel back with the descriptions and are stored with the
    clips."""
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in (CMU_BVH, BANDAI, CMU_ASF, FBX):
        shutil.copy(FIXTURES_DIR / name, folder / name)
    shutil.copy(FIXTURES_DIR / CMU_AMC, folder / "02_01.amc")
    argv = ["import", "--data-dir", str(settings.data_dir), "--no-progress", str(folder)]
    assert main(argv) == 0
    library = open_library(settings)
    try:
        clips = all_clips(library)
        assert sorted(c.format for c in clips) == ["asf/amc", "bvh", "bvh", "fbx"]
        store = previews.preview_store(settings)
        version = previews.preview_version(library)
        for clip in clips:
            assert_same(store.load(clip.content_hash, version), made_on_demand(library, clip))
    finally:
        library.close()


def test_reindex_stores_the_previews_again(library: Library, settings: Settings) -> None:
    """A reindex parses the clips again: the previews of the (new) motion core come with it."""
    upload = Upload.from_files(file=(CMU_BVH, (FIXTURES_DIR / CMU_BVH).read_bytes()))
    clip = ingest(library, upload).clip
    shutil.rmtree(settings.data_dir / PREVIEWS_DIR)
    report = reindex(library, everything=True)
    assert report.recomputed == 1 and not report.failed
    store = previews.preview_store(settings)
    stored = store.load(clip.content_hash, previews.preview_version(library))
    assert_same(stored, made_on_demand(library, clip))
