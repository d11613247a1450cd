"""The clip library: database, stored files and indexes, opened once per process.

``create_app``'s lifespan and the CLI commands call :func:`open_library`, which migrates the
database, then loads every descriptor's index (bringing a file that is behind up to date from
the database, rebuilding one that is missing, unreadable or stale), and hand the
:class:`Library` to the services.

Several processes may write to one data directory at once (the server and ``mocap-index
import``). Each keeps its indexes in memory and follows the database, the source of truth:
clip ids only grow, so :meth:`Library.sync_indexes` adds the vectors of the clips above the
largest id an index has seen. The writes of this process call it after their commit; searches
call :meth:`Library.refresh`, which checks the database at most every
``MOCAP_INDEX_REFRESH_SECONDS``, so clips another process stores become searchable without a
restart. (On PostgreSQL ids come from a sequence, not in commit order: a clip committed by
another process after one with a larger id is missed until the next start, whose count check
adds it. Clips deleted by another process stay in this process's indexes until then, but are
never returned: a search skips ids that have no row.)

The window indexes of moments search (one per windowed descriptor and window length, ids =
window ids of ``clip_windows``, which only grow too) are loaded, synced, refreshed and rebuilt
the same way, beside the clip indexes.
"""

from __future__ import annotations

import logging
import sqlite3
import threading
import time
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
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
from app.index import DescriptorIndex, IndexOptions, IndexSet
from app.services.blobs import BlobStore
from app.services.describe import (
    WINDOW_DESCRIPTORS,
    WINDOW_LENGTHS,
    Describer,
    DescriptorInfo,
    MotionDescriber,
)

log = logging.getLogger(__name__)

DEFAULT_DESCRIPTOR = "posture"


def index_options(settings: Settings) -> IndexOptions:
    """The index kind and search settings of ``MOCAP_INDEX_TYPE`` and friends."""
    return IndexOptions(
        kind=settings.index_type,
        auto_threshold=settings.index_auto_threshold,
        nlist=settings.ivf_nlist,
        nprobe=settings.ivf_nprobe,
    )


class StoredVectors:
    """One descriptor's vectors in the database, read in ``session`` (one snapshot) up to clip
    id ``watermark``: what :meth:`DescriptorIndex.load_or_rebuild` checks an index against."""

    def __init__(self, session: Session, info: DescriptorInfo, watermark: int) -> None:
        self._session = session
        self._info = info
        self._watermark = watermark

    def watermark(self) -> int:
        return self._watermark

    def count(self) -> int:
        return repo.count_vectors(self._session, self._info.name, self._info.version)

    def ids(self) -> np.ndarray:
        info = self._info
        return repo.vector_ids(self._session, info.name, info.version, info.dimension)

    def vectors(self, after: int = 0) -> tuple[np.ndarray, np.ndarray]:
        info = self._info
        return repo.load_vectors(
            self._session,
            info.name,
            info.version,
            info.dimension,
            after=after,
            upto=self._watermark,
        )

    def vectors_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        info = self._info
        return repo.load_vectors_of(
            self._session, info.name, info.version, info.dimension, ids.tolist()
        )


class StoredWindows:
    """One window index's vectors in the database (see :class:`StoredVectors`); ids are
    window ids, ``watermark`` the largest window id of the snapshot."""

    def __init__(self, session: Session, key: repo.WindowKey, watermark: int) -> None:
        self._session = session
        self._key = key
        self._watermark = watermark

    def watermark(self) -> int:
        return self._watermark

    def count(self) -> int:
        return repo.count_windows(self._session, self._key)

    def ids(self) -> np.ndarray:
        return repo.window_ids(self._session, self._key)

    def vectors(self, after: int = 0) -> tuple[np.ndarray, np.ndarray]:
        return repo.load_windows(self._session, self._key, after=after, upto=self._watermark)

    def vectors_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return repo.load_windows_of(self._session, self._key, ids.tolist())


def window_index_name(descriptor: str, length: float) -> str:
    """File stem of the index of ``descriptor`` windows of ``length`` seconds."""
    return f"windows-{descriptor}-{length:g}s"


def window_keys(descriptors: Mapping[str, DescriptorInfo]) -> dict[str, repo.WindowKey]:
    """Every window index: its name -> which windows it holds (the descriptors of
    :data:`WINDOW_DESCRIPTORS` the describer has, at each of :data:`WINDOW_LENGTHS`)."""
    return {
        window_index_name(name, length): repo.WindowKey(
            name, descriptors[name].version, descriptors[name].dimension, length
        )
        for name in WINDOW_DESCRIPTORS
        if name in descriptors
        for length in WINDOW_LENGTHS
    }


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
    # Moments search: one index per window descriptor and length, keyed like window_keys.
    window_indexes: IndexSet = field(default_factory=lambda: IndexSet({}))
    window_keys: dict[str, repo.WindowKey] = field(default_factory=dict)
    write_lock: threading.Lock = field(default_factory=threading.Lock)
    search_reads: repo.SearchReads = field(init=False, repr=False)
    _sync_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _checked_at: float = field(default=0.0, repr=False)

    def __post_init__(self) -> None:
        self.search_reads = repo.SearchReads(self.engine)

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
        with self._sync_lock, self.reads() as session:
            top = repo.max_clip_id(session)
            ids, vectors = repo.load_vectors(
                session, info.name, info.version, info.dimension, upto=top
            )
            self.indexes[name].replace_all(ids, vectors, synced_to=top)

    def rebuild_window_indexes(self) -> None:
        """Refill every window index from the database and save it."""
        with self._sync_lock, self.reads() as session:
            top = repo.max_window_id(session)
            for name, key in self.window_keys.items():
                ids, vectors = repo.load_windows(session, key, upto=top)
                self.window_indexes[name].replace_all(ids, vectors, synced_to=top)

    def sync_indexes(self, *, wait: bool = True) -> bool:
        """Add to the indexes the vectors of clips committed since they last looked (by this
        process or another one). With ``wait=False`` it returns False at once when another
        thread is syncing (that thread brings the indexes up to date)."""
        if not self._sync_lock.acquire(blocking=wait):
            return False
        try:
            with self.reads() as session:  # one snapshot: every clip up to ``top``
                top = repo.max_clip_id(session)
                for name, info in self.descriptors.items():
                    index = self.indexes[name]
                    if index.synced_to >= top:
                        continue
                    ids, vectors = repo.load_vectors(
                        session,
                        info.name,
                        info.version,
                        info.dimension,
                        after=index.synced_to,
                        upto=top,
                    )
                    try:
                        index.add(ids, vectors, synced_to=top)
                    except Exception:
                        # The rows are committed; the index is only a cache of them.
                        log.exception("adding to the %s index failed; rebuilding it", name)
                        everything = repo.load_vectors(
                            session, info.name, info.version, info.dimension, upto=top
                        )
                        index.replace_all(*everything, synced_to=top, persist=False)
                        index.try_save()
                if self.window_keys:
                    self._sync_windows(session)
        finally:
            self._sync_lock.release()
        return True

    def _sync_windows(self, session: Session) -> None:
        top = repo.max_window_id(session)
        for name, key in self.window_keys.items():
            index = self.window_indexes[name]
            if index.synced_to >= top:
                continue
            ids, vectors = repo.load_windows(session, key, after=index.synced_to, upto=top)
            try:
                index.add(ids, vectors, synced_to=top)
            except Exception:
                log.exception("adding to the %s index failed; rebuilding it", name)
                everything = repo.load_windows(session, key, upto=top)
                index.replace_all(*everything, synced_to=top, persist=False)
                index.try_save()

    def _behind(self, db: repo.SearchSnapshot) -> bool:
        top = db.max_clip_id()
        if top > min((index.synced_to for index in self.indexes.values()), default=top):
            return True
        if not self.window_keys:
            return False
        top = db.max_window_id()
        return top > min((index.synced_to for index in self.window_indexes.values()), default=top)

    def refresh(self) -> None:
        """Bring the indexes up to date with the database when the last check is older than
        ``MOCAP_INDEX_REFRESH_SECONDS`` (called before searches; cheap when nothing changed)."""
        now = time.monotonic()
        if now - self._checked_at < self.settings.index_refresh_seconds:
            return
        self._checked_at = now
        try:
            with self.search_reads.snapshot() as db:
                behind = self._behind(db)
            if behind:
                self.sync_indexes(wait=False)
        except (SQLAlchemyError, sqlite3.Error) as exc:  # the indexes as they are still work
            log.warning("could not check the database for new clips: %s", exc)

    def save_indexes(self) -> None:
        """Write the indexes that have unsaved changes (large ones are not saved after every
        change; a file that is behind is brought up to date from the database when loaded)."""
        self.indexes.save(only_changed=True)
        self.window_indexes.save(only_changed=True)

    def clip_count(self) -> int:
        with self.reads() as session:
            return repo.count_clips(session)

    def close(self) -> None:
        try:
            self.save_indexes()
        finally:
            self.search_reads.close()
            self.engine.dispose()


def _open_indexes(
    settings: Settings, reads: sessionmaker[Session], descriptors: Mapping[str, DescriptorInfo]
) -> tuple[IndexSet, IndexSet]:
    """The clip indexes and the window indexes, loaded (or rebuilt) from their files."""
    options = index_options(settings)
    indexes = {
        info.name: DescriptorIndex(
            info.name, info.dimension, info.version, settings.index_dir, options=options
        )
        for info in descriptors.values()
    }
    keys = window_keys(descriptors)
    windows = {
        name: DescriptorIndex(name, key.dimension, key.version, settings.index_dir, options=options)
        for name, key in keys.items()
    }
    # Reading and checksumming the files (hundreds of MB at a million clips) releases the
    # GIL: all at once, in threads.
    every = [*indexes.values(), *windows.values()]
    with ThreadPoolExecutor(max_workers=max(1, min(8, len(every)))) as pool:
        files = dict(zip(every, pool.map(DescriptorIndex.read_file, every), strict=True))
    with reads() as session:  # one snapshot of the database for every index
        watermark = repo.max_clip_id(session)
        for info in descriptors.values():
            source = StoredVectors(session, info, watermark)
            index = indexes[info.name]
            index.load_or_rebuild(source, files.pop(index))
        top = repo.max_window_id(session)
        for name, key in keys.items():
            index = windows[name]
            index.load_or_rebuild(StoredWindows(session, key, top), files.pop(index))
    return IndexSet(indexes), IndexSet(windows)


def open_library(settings: Settings, *, describer: Describer | None = None) -> Library:
    """Migrate the database to the newest schema and load (or rebuild) the indexes."""
    if describer is None:
        describer = MotionDescriber.from_settings(settings)
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
        indexes, windows = _open_indexes(settings, reads, describer.descriptors)
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
        window_indexes=windows,
        window_keys=window_keys(describer.descriptors),
    )
