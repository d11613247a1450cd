"""The change feed keeps its rows for a retention, not forever; a process that was away longer
than that rebuilds its indexes from the database instead of following the feed.

Two libraries on one database are two processes (a server and a replica); each case runs on a
SQLite file and on PostgreSQL. Time is moved by the ``now`` of :func:`prune`.
"""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select

from app.config import Settings
from app.db import vectors as vector_db
from app.db.changes import horizon, prune, pruned_before
from app.db.models import ClipChange
from app.services.clips import delete_clip
from app.services.ingest import ingest
from app.services.library import Library, open_library
from app.services.uploads import Upload
from tests.services.fakes import FakeDescriber, fake_motion

WEEK = timedelta(days=7)


@pytest.fixture(params=["sqlite", "postgresql"])
def settings_pair(request: pytest.FixtureRequest, tmp_path: Path) -> tuple[Settings, Settings]:
    """Settings of a server and of a replica on one database (their own index files)."""
    if request.param == "postgresql":
        url = request.getfixturevalue("postgres_url")
        return (
            Settings(data_dir=tmp_path / "server", database_url=url),
            Settings(data_dir=tmp_path / "replica", database_url=url),
        )
    shared = Settings(data_dir=tmp_path / "data")
    return shared, Settings(data_dir=tmp_path / "data")  # SQLite: one data dir, one writer


def opened(settings: Settings) -> Library:
    return open_library(settings, describer=FakeDescriber())


@pytest.fixture
def server(settings_pair: tuple[Settings, Settings]) -> Iterator[Library]:
    library = opened(settings_pair[0])
    yield library
    library.close()


def store(library: Library, n: int) -> int:
    upload = Upload.from_files(file=(f"clip{n}.bvh", fake_motion([n, n % 3, 1.0])))
    return ingest(library, upload).clip.id


def prune_at(library: Library, now: datetime) -> int:
    with library.writes.begin() as session:
        return prune(session, WEEK, now=now)


def change_rows(library: Library) -> int:
    with library.reads() as session:
        return int(session.execute(select(func.count()).select_from(ClipChange)).scalar_one())


def assert_follows_the_database(library: Library) -> None:
    """Every index holds exactly the database's clips and vectors."""
    with library.reads() as session:
        for name, info in library.descriptors.items():
            ids, vectors = vector_db.load_vectors(session, info.name, info.version, info.dimension)
            index = library.indexes[name]
            assert sorted(index.ids().tolist()) == sorted(ids.tolist()), name
            for clip_id, vector in zip(ids.tolist(), vectors, strict=True):
                np.testing.assert_array_equal(index.reconstruct(clip_id), vector)


def test_rows_older_than_the_retention_go_and_the_position_never_goes_back(
    server: Library,
) -> None:
    start = datetime(2026, 1, 1, tzinfo=UTC)
    for n in range(5):
        store(server, n)
    assert prune_at(server, start) == 0  # a mark, nothing old enough yet
    rows = change_rows(server)
    assert rows >= 5
    with server.reads() as session:
        position = horizon(session)
    assert prune_at(server, start + WEEK / 2) == 0
    assert prune_at(server, start + WEEK + timedelta(hours=1)) == rows
    assert change_rows(server) == 0
    with server.reads() as session:
        assert 0 < pruned_before(session) <= position
        assert horizon(session) >= position  # an empty feed does not move it back
    new = store(server, 10)  # and the feed goes on
    server.sync_indexes()
    assert new in server.indexes["posture"].ids().tolist()
    assert_follows_the_database(server)


def test_a_replica_away_longer_than_the_retention_rebuilds_at_its_start(
    settings_pair: tuple[Settings, Settings], server: Library
) -> None:
    first = [store(server, n) for n in range(4)]
    replica = opened(settings_pair[1])
    replica.close()  # its index files remember where the feed stood
    # Away: one clip deleted and one stored (the same count), then the rows go.
    delete_clip(server, first[0])
    store(server, 20)
    start = datetime.now(UTC)
    prune_at(server, start)
    prune_at(server, start + WEEK + timedelta(hours=1))
    replica = opened(settings_pair[1])
    try:
        assert_follows_the_database(replica)
    finally:
        replica.close()


def test_a_running_replica_left_behind_rebuilds_at_its_next_sync(
    settings_pair: tuple[Settings, Settings], server: Library
) -> None:
    first = [store(server, n) for n in range(4)]
    replica = opened(settings_pair[1])
    try:
        replica.sync_indexes()
        delete_clip(server, first[1])
        store(server, 30)
        start = datetime.now(UTC)
        prune_at(server, start)
        prune_at(server, start + WEEK + timedelta(hours=1))
        replica.sync_indexes()
        assert_follows_the_database(replica)
        store(server, 31)  # and it follows the feed again
        replica.sync_indexes()
        assert_follows_the_database(replica)
    finally:
        replica.close()
