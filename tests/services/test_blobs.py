"""The two blob stores behind one interface: files beside SQLite, rows in PostgreSQL."""

from __future__ import annotations

import errno
import hashlib
import os
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import Engine

from app.config import Settings
from app.db import clips as clip_db
from app.db.migrate import upgrade
from app.db.session import create_db_engine, write_sessions
from app.errors import StorageUnavailable
from app.services import blobs
from app.services.blobs import BlobStore, DatabaseBlobStore, FileBlobStore, open_blob_store
from app.services.clips import clip_download, delete_clip
from app.services.ingest import ingest
from app.services.library import Library, open_library
from app.services.uploads import Upload
from tests.hardening.live import unique_upload


@pytest.fixture(params=["sqlite", "postgresql"])
def engine_on(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Engine]:
    if request.param == "postgresql":
        url = request.getfixturevalue("postgres_url")
    else:
        url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    engine = create_db_engine(url)
    upgrade(engine)
    yield engine
    engine.dispose()


@pytest.fixture
def store(engine_on: Engine, tmp_path: Path) -> BlobStore:
    return open_blob_store(engine_on, tmp_path / "files")


def clip_using(engine: Engine, sha: str) -> None:
    new = clip_db.NewClip(
        name="c", format="bvh", content_hash="c" * 64, frame_count=1, frame_time=0.1,
        duration=0.1, joint_count=1, skeleton_family="x", lead_in_frames=0, labels=(),
        files=(clip_db.FileRecord("file", "c.bvh", sha, 1),), vectors={},
        created_at=datetime.now(UTC),
    )  # fmt: skip
    with write_sessions(engine).begin() as session:
        clip_db.insert_clips(session, [new])


def test_the_backend_decides_the_store(engine_on: Engine, store: BlobStore) -> None:
    postgres = engine_on.dialect.name == "postgresql"
    assert isinstance(store, DatabaseBlobStore if postgres else FileBlobStore)


def test_put_read_delete(store: BlobStore) -> None:
    sha, new = store.put(b"HIERARCHY\n")
    assert new and len(sha) == 64 and store.exists(sha)
    assert store.put(b"HIERARCHY\n") == (sha, False)  # the same bytes are stored once
    assert store.read(sha) == b"HIERARCHY\n"
    store.delete(sha)
    assert not store.exists(sha)
    with pytest.raises(StorageUnavailable):
        store.read(sha)
    with pytest.raises(ValueError):
        store.read("../../etc/passwd")


def test_unreferenced_files_go_after_the_grace(engine_on: Engine, store: BlobStore) -> None:
    used, _ = store.put(b"used")
    orphan, _ = store.put(b"orphan")
    clip_using(engine_on, used)
    with write_sessions(engine_on).begin() as session:
        assert store.remove_unreferenced(session, older_than=time.time() - 60) == 0  # too new
    with write_sessions(engine_on).begin() as session:
        assert store.remove_unreferenced(session, older_than=time.time() + 1) == 1
    assert store.exists(used) and not store.exists(orphan)


def test_put_many_stores_all_or_none(store: BlobStore, monkeypatch: pytest.MonkeyPatch) -> None:
    files = [
        (f"clip {i}".encode(), hashlib.sha256(f"clip {i}".encode()).hexdigest()) for i in range(4)
    ]
    kept, _ = store.put(files[0][0])
    stored = store.put_many([*files, files[1]])  # one stored before, one given twice
    assert stored == [(kept, False), *((sha, True) for _, sha in files[1:]), (files[1][1], False)]
    assert all(store.read(sha) == data for data, sha in files)
    for _, sha in files[1:]:
        store.delete(sha)
    if isinstance(store, FileBlobStore):
        real_replace = os.replace

        def full_disk(source: str, target: str) -> None:
            if len(list(store.stored())) == 2:  # the one kept and one new file: then it fails
                raise OSError(errno.ENOSPC, "No space left on device")
            real_replace(source, target)

        monkeypatch.setattr(blobs.os, "replace", full_disk)
        with pytest.raises(StorageUnavailable, match="No space left"):
            store.put_many(files)
        assert [sha for sha, _ in store.stored()] == [kept]
        assert list(store.temporary_files()) == []


# -- a delete in one process, a commit against the same file in another -------------------
#
# Two libraries on one database are two processes (replicas, `serve --workers N`, an import
# beside the server): each has its own write lock. Process B stores a clip whose skeleton file
# is already stored for clip X; process A deletes X. Whatever the order, B's clip must keep
# its file. Each interleaving is forced with events, not left to timing.


@pytest.fixture
def two_libraries(
    request: pytest.FixtureRequest, tmp_path: Path
) -> Iterator[tuple[Library, Library]]:
    url = None
    if request.param == "postgresql":
        url = request.getfixturevalue("postgres_url")
    opened = []
    for name in ("a", "b"):
        data_dir = tmp_path / (name if url else "shared")
        opened.append(open_library(Settings(data_dir=data_dir, database_url=url)))
    try:
        yield opened[0], opened[1]
    finally:
        for library in opened:
            library.close()


def amc_upload(n: int) -> Upload:
    fields = unique_upload(3 * n + 2)  # an ASF skeleton (the same bytes every time) + AMC
    return Upload.from_files(skeleton=fields["skeleton"], motion=fields["motion"])


def store_in_background(library: Library, upload: Upload) -> tuple[threading.Thread, list[Any]]:
    result: list[Any] = []

    def run() -> None:
        try:
            result.append(ingest(library, upload))
        except BaseException as error:  # reported by the test
            result.append(error)

    thread = threading.Thread(target=run)
    thread.start()
    return thread, result


def check_stored(library: Library, result: list[Any]) -> None:
    assert len(result) == 1 and not isinstance(result[0], BaseException), result
    clip = result[0].clip
    for record in clip.files:
        assert library.blobs.read(record.sha256)  # StorageUnavailable when it went
    assert clip_download(library, clip, "skeleton").data == unique_upload(2)["skeleton"][1]


@pytest.mark.parametrize("two_libraries", ["sqlite", "postgresql"], indirect=True)
def test_a_delete_between_the_others_file_write_and_commit(
    two_libraries: tuple[Library, Library], monkeypatch: pytest.MonkeyPatch
) -> None:
    a, b = two_libraries
    x = ingest(a, amc_upload(0)).clip
    written, go_on = threading.Event(), threading.Event()
    real_put_many = b.blobs.put_many

    def put_many_then_wait(files: Any) -> Any:
        stored = real_put_many(files)  # the skeleton was there: not written again
        if not written.is_set():
            written.set()
            assert go_on.wait(30)
        return stored

    monkeypatch.setattr(b.blobs, "put_many", put_many_then_wait)
    thread, result = store_in_background(b, amc_upload(1))
    assert written.wait(30)
    delete_clip(a, x.id)  # X's skeleton is unreferenced now: it may go
    go_on.set()
    thread.join(60)
    check_stored(b, result)
    check_stored(a, result)


@pytest.mark.parametrize("two_libraries", ["sqlite", "postgresql"], indirect=True)
def test_a_delete_while_the_other_commits(
    two_libraries: tuple[Library, Library], monkeypatch: pytest.MonkeyPatch
) -> None:
    a, b = two_libraries
    x = ingest(a, amc_upload(0)).clip
    inserted, go_on = threading.Event(), threading.Event()
    real_insert = clip_db.insert_clips

    def insert_then_wait(session: Any, rows: Any) -> Any:
        ids = real_insert(session, rows)  # in B's transaction, not committed yet
        inserted.set()
        assert go_on.wait(30)
        return ids

    monkeypatch.setattr(clip_db, "insert_clips", insert_then_wait)
    thread, result = store_in_background(b, amc_upload(1))
    assert inserted.wait(30)
    deleting = threading.Thread(target=delete_clip, args=(a, x.id))
    deleting.start()
    deleting.join(0.5)  # it may wait for B's transaction (SQLite's lock, a row lock)
    go_on.set()
    thread.join(60)
    deleting.join(60)
    assert not deleting.is_alive()
    check_stored(b, result)
    check_stored(a, result)
