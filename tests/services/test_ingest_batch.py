"""Batches through the one ingest path, and two libraries (two processes) on one data dir."""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from app.config import Settings
from app.errors import StorageUnavailable
from app.services import blobs
from app.services import clips as clip_service
from app.services.ingest import describe, store_many
from app.services.library import Library, open_library
from app.services.search import search_by_clip_id, search_vector
from app.services.uploads import Upload
from tests.services.fakes import FakeDescriber, fake_motion


def bvh(posture: list[float], name: str) -> Upload:
    return Upload.from_files(file=(f"{name}.bvh", fake_motion(posture)), labels=[name[:1]])


@pytest.fixture
def fresh(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data", index_refresh_seconds=0)


@pytest.fixture
def library(fresh: Settings) -> Iterator[Library]:
    library = open_library(fresh, describer=FakeDescriber())
    yield library
    library.close()


def test_a_batch_is_stored_in_order_and_searchable_at_once(library: Library) -> None:
    uploads = [bvh([i, 0, 0], f"c{i}") for i in range(50)]
    results = store_many(library, [describe(library, u) for u in uploads])
    assert [r.clip.name for r in results] == [f"c{i}" for i in range(50)]
    assert [r.clip.id for r in results] == list(range(1, 51))
    assert all(r.created for r in results)
    assert library.indexes.sizes() == {"posture": 50, "kinetic": 50}
    # The feed's next row (SQLite): a row per clip and one per label (migration 0009).
    assert library.indexes["posture"].synced_to == 101
    hits = search_vector(library, "posture", np.array([10.2, 0, 0], np.float32), 3)
    assert [h.clip.name for h in hits] == ["c10", "c11", "c9"]
    assert hits[0].clip.labels == ("c",)


def test_a_failed_file_write_leaves_no_file_and_no_row(
    library: Library, fresh: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_replace = os.replace
    calls = {"n": 0}

    def flaky_replace(source: str | Path, target: str | Path) -> None:
        calls["n"] += 1
        if calls["n"] == 3:  # two files are in place already
            raise OSError(errno.ENOSPC, "No space left on device")
        real_replace(source, target)

    monkeypatch.setattr(blobs.os, "replace", flaky_replace)
    uploads = [bvh([i, 1, 0], f"f{i}") for i in range(6)]
    with pytest.raises(StorageUnavailable):
        store_many(library, [describe(library, u) for u in uploads])
    assert library.clip_count() == 0
    assert [p for p in fresh.files_dir.rglob("*") if p.is_file()] == []


def test_clips_stored_by_another_process_are_found_without_a_restart(
    library: Library, fresh: Settings
) -> None:
    [mine] = store_many(library, [describe(library, bvh([0, 0, 0], "mine"))])
    other = open_library(fresh, describer=FakeDescriber())  # e.g. mocap-index import
    try:
        theirs = store_many(other, [describe(other, bvh([i, 0, 0], f"t{i}")) for i in (1, 2)])
    finally:
        other.close()
    # Not yet in this library's indexes; the next search looks at the database first.
    assert library.indexes["posture"].size == 1
    _, hits = search_by_clip_id(library, mine.clip.id, "posture", 5, label=None)
    assert [h.clip.id for h in hits] == [r.clip.id for r in theirs]
    assert library.indexes.sizes() == {"posture": 3, "kinetic": 3}
    # With a label filter too.
    _, hits = search_by_clip_id(library, mine.clip.id, "kinetic", 5, label="t")
    assert sorted(h.clip.id for h in hits) == sorted(r.clip.id for r in theirs)


def test_a_clip_deleted_by_another_process_is_never_returned(
    library: Library, fresh: Settings
) -> None:
    results = store_many(library, [describe(library, bvh([i, 0, 0], f"d{i}")) for i in range(5)])
    other = open_library(fresh, describer=FakeDescriber())
    try:
        clip_service.delete_clip(other, results[1].clip.id)
    finally:
        other.close()
    assert library.indexes["posture"].size == 5  # this process still holds its vector
    _, hits = search_by_clip_id(library, results[0].clip.id, "posture", 3, label=None)
    assert [h.clip.name for h in hits] == ["d2", "d3", "d4"]  # d1 skipped, still 3 hits
    library.close()
    reopened = open_library(fresh, describer=FakeDescriber())
    try:
        assert reopened.indexes.sizes() == {"posture": 4, "kinetic": 4}
    finally:
        reopened.close()


def test_index_files_of_a_killed_writer_catch_up_at_start(fresh: Settings) -> None:
    library = open_library(fresh, describer=FakeDescriber())
    for index in library.indexes.values():
        index.autosave = False  # as during an import: saved only at the end
    store_many(library, [describe(library, bvh([i, 0, 0], f"k{i}")) for i in range(4)])
    library.engine.dispose()  # "killed": never closed, so the files were not saved
    reopened = open_library(fresh, describer=FakeDescriber())
    try:
        assert reopened.indexes.sizes() == {"posture": 4, "kinetic": 4}
        # Past the feed's 8 rows (SQLite): each clip's and its label's (migration 0009).
        assert reopened.indexes["posture"].synced_to == 9
    finally:
        reopened.close()
