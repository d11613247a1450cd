"""Ingest, delete and reindex on a real database, files and indexes, with a fake motion core."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy.exc import OperationalError

from app.config import Settings
from app.db import clips as clip_db
from app.errors import (
    DescriptorOutdated,
    MocapError,
    NotFound,
    ParseError,
    StorageUnavailable,
)
from app.services import clips as clip_service
from app.services import ingest as ingest_service
from app.services.describe import DescriptorInfo
from app.services.ingest import ingest, ingest_many
from app.services.library import Library, open_library
from app.services.reindex import reindex
from app.services.search import search_by_clip
from app.services.uploads import Upload
from tests.services.fakes import FAKE_DESCRIPTORS, FakeDescriber, fake_motion


@pytest.fixture
def describer() -> FakeDescriber:
    return FakeDescriber()


@pytest.fixture
def library(settings: Settings, describer: FakeDescriber) -> Iterator[Library]:
    library = open_library(settings, describer=describer)
    yield library
    library.close()


def bvh(posture: list[float], name: str = "clip.bvh", labels: list[str] | None = None) -> Upload:
    return Upload.from_files(file=(name, fake_motion(posture)), labels=labels)


def stored_files(settings: Settings) -> list[Path]:
    return sorted(p for p in settings.files_dir.rglob("*") if p.is_file())


def row_count(library: Library) -> int:
    return library.clip_count()


def test_ingest_stores_row_vectors_file_and_index(library: Library, settings: Settings) -> None:
    result = ingest(library, bvh([1, 2, 3], labels=["x"]))
    assert result.created
    clip = result.clip
    assert clip.name == "clip" and clip.format == "bvh" and clip.frame_count == 10
    vectors = clip_service.clip_vectors(library, clip.id)
    np.testing.assert_array_equal(vectors["posture"].vector, [1, 2, 3])
    assert library.indexes.sizes() == {"posture": 1, "kinetic": 1}
    files = stored_files(settings)
    assert [f.name for f in files] == [clip.files[0].sha256]
    assert files[0].read_bytes() == fake_motion([1, 2, 3])


def test_same_content_is_stored_once_and_not_described_again(
    library: Library, describer: FakeDescriber
) -> None:
    first = ingest(library, bvh([1, 2, 3]))
    calls = describer.calls
    again = ingest(library, bvh([1, 2, 3], name="other.bvh"))
    assert not again.created and again.clip.id == first.clip.id
    assert again.clip.name == "clip"  # the existing clip, unchanged
    assert describer.calls == calls
    assert row_count(library) == 1


def test_unreadable_upload_leaves_nothing(library: Library, settings: Settings) -> None:
    with pytest.raises(ParseError, match="line 1"):
        ingest(library, Upload.from_files(file=("bad.bvh", b"{not json")))
    assert row_count(library) == 0
    assert stored_files(settings) == []
    assert library.indexes.sizes() == {"posture": 0, "kinetic": 0}


def test_failed_commit_removes_the_stored_file(
    library: Library, settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken_insert(*args: object, **kwargs: object) -> list[int]:
        raise OperationalError("INSERT", {}, Exception("disk I/O error"))

    monkeypatch.setattr(clip_db, "insert_clips", broken_insert)
    with pytest.raises(StorageUnavailable):
        ingest(library, bvh([1, 2, 3]))
    assert stored_files(settings) == []
    assert row_count(library) == 0
    assert library.indexes.sizes() == {"posture": 0, "kinetic": 0}


def test_race_with_another_process_returns_its_clip(
    library: Library, settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Another writer stores the same content between our look-up and our insert: the UNIQUE
    # content hash refuses our row, and we return theirs without deleting the shared file.
    upload = bvh([1, 2, 3])
    theirs = ingest(library, upload).clip
    real_lookup = clip_db.clip_ids_by_hash
    calls = {"n": 0}

    def stale_lookup(session: object, hashes: object) -> dict[str, int]:
        calls["n"] += 1
        return {} if calls["n"] == 1 else real_lookup(session, hashes)  # type: ignore[arg-type]

    monkeypatch.setattr(clip_db, "clip_ids_by_hash", stale_lookup)
    described = ingest_service.describe(library, upload)
    [result] = ingest_service.store_many(library, [described])
    assert not result.created and result.clip.id == theirs.id
    assert [f.name for f in stored_files(settings)] == [theirs.files[0].sha256]
    assert library.indexes.sizes()["posture"] == 1


def test_concurrent_identical_uploads_create_one_clip(library: Library) -> None:
    results: list[ingest_service.IngestResult] = []
    barrier = threading.Barrier(4)

    def upload() -> None:
        barrier.wait()
        results.append(ingest(library, bvh([4, 5, 6])))

    threads = [threading.Thread(target=upload) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sum(r.created for r in results) == 1
    assert len({r.clip.id for r in results}) == 1
    assert row_count(library) == 1 and library.indexes["posture"].size == 1


def test_ingest_many_batches_skips_bad_files_and_duplicates(library: Library) -> None:
    errors: list[tuple[str, MocapError]] = []
    uploads = [bvh([i, 0, 0], name=f"c{i}.bvh") for i in range(5)]
    uploads.insert(2, Upload.from_files(file=("bad.bvh", b"nope")))
    uploads.append(bvh([1, 0, 0], name="dup.bvh"))  # same bytes as c1
    results = ingest_many(
        library, uploads, batch_size=2, on_error=lambda u, e: errors.append((u.clip_name, e))
    )
    assert [r.clip.name for r in results] == ["c0", "c1", "c2", "c3", "c4", "c1"]
    assert [r.created for r in results] == [True] * 5 + [False]
    assert [name for name, _ in errors] == ["bad"]
    assert library.indexes.sizes() == {"posture": 5, "kinetic": 5}
    with pytest.raises(ParseError):
        ingest_many(library, [Upload.from_files(file=("bad.bvh", b"nope"))])


def test_repeated_content_within_a_batch_is_stored_once(library: Library) -> None:
    same = fake_motion([7, 7, 7])
    uploads = [Upload.from_files(file=(f"{n}.bvh", same)) for n in "abc"]
    results = ingest_many(library, uploads)
    assert [r.created for r in results] == [True, False, False]
    assert len({r.clip.id for r in results}) == 1


def test_delete_keeps_files_other_clips_use(library: Library, settings: Settings) -> None:
    skeleton = ("02.asf", b"shared skeleton")
    one = ingest(
        library, Upload.from_files(skeleton=skeleton, motion=("a.amc", fake_motion([1, 0, 0])))
    )
    two = ingest(
        library, Upload.from_files(skeleton=skeleton, motion=("b.amc", fake_motion([2, 0, 0])))
    )
    assert len(stored_files(settings)) == 3  # one skeleton, two motions
    clip_service.delete_clip(library, one.clip.id)
    assert len(stored_files(settings)) == 2
    assert library.indexes.sizes() == {"posture": 1, "kinetic": 1}
    with pytest.raises(NotFound):
        clip_service.delete_clip(library, one.clip.id)
    clip_service.delete_clip(library, two.clip.id)
    assert stored_files(settings) == []
    assert library.indexes.sizes() == {"posture": 0, "kinetic": 0}


def test_reindex_recomputes_outdated_vectors(settings: Settings) -> None:
    library = open_library(settings, describer=FakeDescriber())
    clip = ingest(library, bvh([1, 2, 3])).clip
    other = ingest(library, bvh([1, 2, 4], name="b.bvh")).clip
    library.close()

    # A new version of "kinetic" (now 3 numbers) and a new descriptor.
    newer = {
        **FAKE_DESCRIPTORS,
        "kinetic": DescriptorInfo("kinetic", 3, 2, "fake kinetic v2"),
        "extra": DescriptorInfo("extra", 4, 1, "new"),
    }
    library = open_library(settings, describer=FakeDescriber(newer))
    try:
        assert library.indexes.sizes() == {"posture": 2, "kinetic": 0, "extra": 0}
        with pytest.raises(DescriptorOutdated, match="mocap-index reindex"):
            search_by_clip(library, clip, "kinetic", 5, label=None)
        report = reindex(library)
        assert report.recomputed == 2 and not report.failed
        assert report.index_sizes == {"posture": 2, "kinetic": 2, "extra": 2}
        hits = search_by_clip(library, clip, "kinetic", 5, label=None)
        assert [h.clip.id for h in hits] == [other.id]
        stored = clip_service.clip_vectors(library, clip.id)["kinetic"]
        assert stored.version == 2 and stored.vector.shape == (3,)
        assert reindex(library).recomputed == 0  # nothing left to do
        assert reindex(library, everything=True).recomputed == 2
    finally:
        library.close()


def test_reindex_drops_outdated_vectors_it_cannot_recompute(settings: Settings) -> None:
    """A stored file that no longer describes (here: damaged on disk) must not keep the
    library refusing searches: its outdated vectors go, the clip stays, the failure is
    reported."""
    library = open_library(settings, describer=FakeDescriber())
    good = ingest(library, bvh([1, 2, 3])).clip
    bad = ingest(library, bvh([1, 2, 4], name="b.bvh")).clip
    library.blobs.path(bad.files[0].sha256).write_bytes(b"not json any more")
    library.close()

    newer = {**FAKE_DESCRIPTORS, "kinetic": DescriptorInfo("kinetic", 3, 2, "fake kinetic v2")}
    library = open_library(settings, describer=FakeDescriber(newer))
    try:
        report = reindex(library)
        assert report.recomputed == 1 and set(report.failed) == {bad.id}
        assert "not JSON" in report.failed[bad.id]
        assert search_by_clip(library, good, "kinetic", 5, label=None) == []
        assert "kinetic" not in clip_service.clip_vectors(library, bad.id)
        assert clip_service.clip_vectors(library, bad.id)["posture"].version == 1
    finally:
        library.close()


def test_a_duplicate_upload_cannot_take_a_clip_past_the_label_cap(settings: Settings) -> None:
    from fastapi.testclient import TestClient

    from app.labels import MAX_LABELS
    from app.main import create_app
    from tests.hardening.live import unique_upload

    stored = [f"take {n}" for n in range(MAX_LABELS - 5)]
    more = [f"extra {n}" for n in range(10)]
    with TestClient(create_app(settings)) as client:
        clip = client.post("/clips", files=unique_upload(0), data={"labels": stored}).json()
        again = client.post("/clips", files=unique_upload(0), data={"labels": more})
        assert again.status_code == 422, again.text
        detail = again.json()["detail"]
        assert f"cap of {MAX_LABELS} labels" in detail and f"clip {clip['id']}" in detail
        assert client.get(f"/clips/{clip['id']}").json()["labels"] == stored
        # up to the cap is fine
        within = client.post("/clips", files=unique_upload(0), data={"labels": more[:5]})
        assert within.status_code == 200, within.text
        assert len(within.json()["labels"]) == MAX_LABELS


def test_a_batch_keeps_going_when_a_duplicate_would_pass_the_label_cap(
    library: Library,
) -> None:
    from app.labels import MAX_LABELS

    stored = [f"take {n}" for n in range(MAX_LABELS - 1)]
    first = ingest(library, bvh([1, 2, 3], labels=stored)).clip
    results = ingest_many(
        library, [bvh([1, 2, 3], labels=["a", "b"]), bvh([4, 5, 6], name="new.bvh")]
    )
    assert [r.created for r in results] == [False, True]
    labels = clip_service.get_clip(library, first.id).labels
    assert labels == (*stored, "a")
