"""The two blob stores behind one interface: files beside SQLite, rows in PostgreSQL."""

from __future__ import annotations

import errno
import hashlib
import os
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import pytest
from sqlalchemy import Engine

from app.db import clips as clip_db
from app.db.migrate import upgrade
from app.db.session import create_db_engine, write_sessions
from app.errors import StorageUnavailable
from app.services import blobs
from app.services.blobs import BlobStore, DatabaseBlobStore, FileBlobStore, open_blob_store


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
