"""The change feed the indexes follow (app/db/changes.py), against real databases.

The case it exists for: on PostgreSQL two transactions take clip ids 1 and 2 from the
sequence, and the one holding the lower id commits last. A reader that follows the largest id
it has seen skips clip 1 for good; the feed must not.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.config import Settings
from app.db import clips as clip_db
from app.db.changes import ChangeFeed
from app.db.models import Clip
from app.services.ingest import describe, new_clip
from app.services.library import Library, open_library
from app.services.search import search_vector
from app.services.uploads import Upload
from tests.services.fakes import FakeDescriber, fake_motion


def row(library: Library, n: int) -> clip_db.NewClip:
    upload = Upload.from_files(file=(f"c{n}.bvh", fake_motion([float(n), 0, 0])), labels=["c"])
    return new_clip(library, describe(library, upload))


@pytest.fixture(params=["sqlite", "postgresql"])
def settings_on(request: pytest.FixtureRequest, tmp_path: Path) -> Settings:
    url = request.getfixturevalue("postgres_url") if request.param == "postgresql" else None
    return Settings(data_dir=tmp_path / "data", database_url=url, index_refresh_seconds=0)


@pytest.fixture
def reader(settings_on: Settings) -> Iterator[Library]:
    """A library (as one replica) whose indexes follow the feed."""
    library = open_library(settings_on, describer=FakeDescriber())
    yield library
    library.close()


@pytest.fixture
def writer(settings_on: Settings) -> Iterator[Library]:
    """Another library on the same database (as another replica or an import)."""
    library = open_library(settings_on, describer=FakeDescriber())
    yield library
    library.close()


def indexed(library: Library) -> set[int]:
    ids = [set(index.ids().tolist()) for index in library.indexes.values()]
    assert all(i == ids[0] for i in ids), "the indexes disagree"
    return ids[0]


def test_lower_id_committing_last_is_not_missed(
    request: pytest.FixtureRequest, postgres_url: str, tmp_path: Path
) -> None:
    settings = Settings(data_dir=tmp_path / "data", database_url=postgres_url)
    reader = open_library(settings, describer=FakeDescriber())
    request.addfinalizer(reader.close)
    first, second = Session(reader.engine), Session(reader.engine)
    try:
        (low,) = clip_db.insert_clips(first, [row(reader, 1)])  # transaction 1: id 1, open
        (high,) = clip_db.insert_clips(second, [row(reader, 2)])  # transaction 2: id 2
        assert low < high
        second.commit()
        reader.sync_indexes()
        assert indexed(reader) == {high}
        # What following "the largest id seen" would now believe: nothing below 2 is left.
        with reader.reads() as session:
            assert session.scalar(select(func.max(Clip.id))) == high
        first.commit()  # the lower id becomes visible only now
    finally:
        first.close()
        second.close()
    reader.sync_indexes()
    assert indexed(reader) == {low, high}
    hits = search_vector(reader, "posture", np.array([1.0, 0, 0], np.float32), 2)
    assert [h.clip.id for h in hits] == [low, high]


def test_rolled_back_and_running_transactions(postgres_url: str, tmp_path: Path) -> None:
    # A transaction that never commits leaves no row; one that runs across several polls
    # holds the position back without making the reader apply others' rows twice.
    settings = Settings(data_dir=tmp_path / "data", database_url=postgres_url)
    library = open_library(settings, describer=FakeDescriber())
    try:
        feed = ChangeFeed(library.indexes["posture"].synced_to)
        with Session(library.engine) as aborted:
            clip_db.insert_clips(aborted, [row(library, 1)])
            aborted.rollback()
        long = Session(library.engine)
        (pending,) = clip_db.insert_clips(long, [row(library, 2)])  # holds the horizon back
        with library.writes.begin() as session:
            (done,) = clip_db.insert_clips(session, [row(library, 3)])
        with library.reads() as session:
            poll = feed.poll(session)
        assert poll.clip_ids.tolist() == [done]
        feed.advance(poll)
        with library.reads() as session:
            again = feed.poll(session)
        assert again.clip_ids.tolist() == []  # seen, though still after the position
        long.commit()
        long.close()
        with library.reads() as session:
            last = feed.poll(session)
        assert last.clip_ids.tolist() == [pending]
        feed.advance(last)
        assert feed.position >= last.position
    finally:
        library.close()


def test_another_process_sees_adds_and_deletes(reader: Library, writer: Library) -> None:
    with writer.writes.begin() as session:
        ids = clip_db.insert_clips(session, [row(writer, n) for n in range(5)])
    reader.sync_indexes()
    assert indexed(reader) == set(ids)
    from app.services.clips import delete_clip

    delete_clip(writer, ids[0])
    assert ids[0] not in indexed(writer)  # its own delete, at once
    reader.refresh()  # as before a search (MOCAP_INDEX_REFRESH_SECONDS=0)
    assert indexed(reader) == set(ids[1:])


def test_a_replica_started_later_catches_up_from_its_saved_index(
    settings_on: Settings, writer: Library, tmp_path: Path
) -> None:
    with writer.writes.begin() as session:
        ids = clip_db.insert_clips(session, [row(writer, n) for n in range(6)])
    # its own data directory (index files), the same database
    other = settings_on.model_copy(
        update={"data_dir": tmp_path / "replica", "database_url": settings_on.sqlalchemy_url}
    )
    replica = open_library(other, describer=FakeDescriber())
    assert indexed(replica) == set(ids)  # built from the database at start
    replica.indexes.save(only_changed=False)
    replica.close()
    # meanwhile: two deleted, two added
    from app.services.clips import delete_clip

    for clip_id in ids[:2]:
        delete_clip(writer, clip_id)
    with writer.writes.begin() as session:
        more = clip_db.insert_clips(session, [row(writer, n) for n in range(10, 12)])
    replica = open_library(other, describer=FakeDescriber())
    try:
        assert indexed(replica) == set(ids[2:]) | set(more)
    finally:
        replica.close()


def test_the_first_search_of_a_process_sees_what_another_stored_since_it_opened(
    settings_on: Settings,
) -> None:
    """With a refresh interval (a served process), the thread that follows the feed used to
    start at the first search and that search answered from the indexes as loaded at start:
    a worker that had not searched yet missed every clip the other worker had stored."""
    following = settings_on.model_copy(update={"index_refresh_seconds": 60.0})
    reader = open_library(following, describer=FakeDescriber())
    writer = open_library(following, describer=FakeDescriber())
    try:
        with writer.writes.begin() as session:
            ids = clip_db.insert_clips(session, [row(writer, n) for n in range(3)])
        query = np.zeros(3, dtype=np.float32)
        hits = search_vector(reader, "posture", query, 10)
        assert {hit.clip.id for hit in hits} == set(ids)
    finally:
        writer.close()
        reader.close()


def test_a_replica_forgets_its_previews_of_clips_deleted_elsewhere(
    settings_on: Settings, writer: Library, tmp_path: Path
) -> None:
    """A replica with a data directory of its own stores previews there; a clip deleted
    through another replica must not leave its motion on this one's disk."""
    from app.services.clips import delete_clip
    from app.services.library_sync import rebuild_all
    from app.services.preview_store import preview_store

    with writer.writes.begin() as session:
        ids = clip_db.insert_clips(session, [row(writer, n) for n in range(4)])
        hashes = [clip_db.content_hashes(session, [clip_id])[0] for clip_id in ids]
    other = settings_on.model_copy(
        update={"data_dir": tmp_path / "replica", "database_url": settings_on.sqlalchemy_url}
    )
    replica = open_library(other, describer=FakeDescriber())
    try:
        store = preview_store(replica.settings)
        paths = [store.path(h, "v1") for h in hashes]
        for path in paths:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"a stored preview")
        delete_clip(writer, ids[0])
        replica.refresh()  # follows the feed, as before a search
        assert [p.exists() for p in paths] == [False, True, True, True]
        # Away longer than the feed keeps its rows: the rebuild compares contents instead.
        delete_clip(writer, ids[1])
        with replica.sync_lock, replica.reads() as session:
            rebuild_all(replica, session)
        assert [p.exists() for p in paths] == [False, False, True, True]
    finally:
        replica.close()
