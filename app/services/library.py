"""The clip library: database, stored files and indexes, opened once per process.

``create_app``'s lifespan and the CLI commands call :func:`open_library`, which migrates the
database, then loads every descriptor's index (rebuilding it from the database when it is
missing, unreadable or stale), and hand the :class:`Library` to the services.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from sqlalchemy import Engine
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import repository as repo
from app.db.migrate import upgrade
from app.db.session import create_db_engine, read_sessions, write_sessions
from app.errors import InvalidInput, StorageUnavailable
from app.index import DescriptorIndex, IndexSet
from app.services.blobs import BlobStore
from app.services.describe import Describer, DescriptorInfo, MotionDescriber

log = logging.getLogger(__name__)

DEFAULT_DESCRIPTOR = "posture"


@dataclass
class Library:
    """Everything the services work on.

    ``write_lock`` serialises the writes of this process (store files -> commit -> update the
    indexes; delete -> drop from the indexes -> remove files), so those three stores never
    disagree in a way another request can see. Reads and searches do not take it.
    """

    settings: Settings
    engine: Engine
    reads: sessionmaker[Session]
    writes: sessionmaker[Session]
    blobs: BlobStore
    indexes: IndexSet
    describer: Describer
    write_lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def descriptors(self) -> Mapping[str, DescriptorInfo]:
        return self.describer.descriptors

    def descriptor(self, name: str) -> DescriptorInfo:
        """The descriptor called ``name``; :class:`InvalidInput` (422) names the known ones."""
        try:
            return self.descriptors[name]
        except KeyError:
            known = ", ".join(self.descriptors)
            raise InvalidInput(f"descriptor: unknown {name!r}; choose one of {known}") from None

    def rebuild_index(self, name: str) -> None:
        """Refill one index from the database (the source of truth) and save it."""
        info = self.descriptors[name]
        with self.reads() as session:
            ids, vectors = repo.load_vectors(session, info.name, info.version, info.dimension)
        self.indexes[name].replace_all(ids, vectors)

    def clip_count(self) -> int:
        with self.reads() as session:
            return repo.count_clips(session)

    def close(self) -> None:
        self.engine.dispose()


def _open_indexes(
    settings: Settings, reads: sessionmaker[Session], descriptors: Mapping[str, DescriptorInfo]
) -> IndexSet:
    indexes = {}
    for info in descriptors.values():
        index = DescriptorIndex(info.name, info.dimension, info.version, settings.index_dir)
        with reads() as session:
            expected = repo.vector_ids(session, info.name, info.version, info.dimension)

        def load(info: DescriptorInfo = info) -> tuple[np.ndarray, np.ndarray]:
            with reads() as session:
                return repo.load_vectors(session, info.name, info.version, info.dimension)

        index.load_or_rebuild(expected, load)
        indexes[info.name] = index
    return IndexSet(indexes)


def open_library(settings: Settings, *, describer: Describer | None = None) -> Library:
    """Migrate the database to the newest schema and load (or rebuild) the indexes."""
    describer = describer if describer is not None else MotionDescriber()
    if DEFAULT_DESCRIPTOR not in describer.descriptors:
        raise RuntimeError(f"the default descriptor {DEFAULT_DESCRIPTOR!r} is not registered")
    try:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        engine = create_db_engine(settings.sqlalchemy_url)
        upgrade(engine)
    except (OSError, SQLAlchemyError) as exc:
        raise StorageUnavailable(f"cannot open the database: {exc}") from exc
    reads = read_sessions(engine)
    try:
        indexes = _open_indexes(settings, reads, describer.descriptors)
        with reads() as session:
            clips = repo.count_clips(session)
    except BaseException:
        engine.dispose()
        raise
    for name, size in indexes.sizes().items():
        if size < clips:
            log.warning(
                "%d of %d clips have no current %r vector and cannot be found with it; "
                "run `mocap-index reindex`",
                clips - size,
                clips,
                name,
            )
    return Library(
        settings=settings,
        engine=engine,
        reads=reads,
        writes=write_sessions(engine),
        blobs=BlobStore(settings.files_dir),
        indexes=indexes,
        describer=describer,
    )
