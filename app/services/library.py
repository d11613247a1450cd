"""The clip library: database, stored files and indexes, opened once per process.

``create_app``'s lifespan and the CLI commands call :func:`open_library`, which migrates the
database, then loads every descriptor's index (bringing a file that is behind up to date from
the database, rebuilding one that is missing, unreadable or stale; see
:mod:`app.services.library_caches`), and hand the :class:`Library` to the services.

Several processes may write to one database at once (``mocap-index serve`` replicas, on one
machine or several, and ``mocap-index import``). Each keeps its indexes in memory and follows
the database, the source of truth, through its change feed (:mod:`app.db.changes`: a row per
clip added or deleted, written by triggers): :meth:`Library.sync_indexes` applies the clips
changed since it last looked (:mod:`app.services.library_sync`). The writes of this process
call it after their commit; searches call :meth:`Library.refresh`, which looks at most every
``MOCAP_INDEX_REFRESH_SECONDS``, so clips another process stores or deletes are found, or no
longer found, without a restart. On PostgreSQL the feed also catches a clip whose
transaction commits after one with a larger id.

The window indexes of moments search (one per windowed descriptor and window length, ids =
window ids of ``clip_windows``) are loaded, rebuilt and kept up to date the same way, from the
same feed: a clip's windows come and go with it; where each window lies (the places) is
loaded and saved by :mod:`app.services.library_places`.
"""

from __future__ import annotations

import logging
import sqlite3
import threading
import time
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import timedelta

import numpy as np
from sqlalchemy import Engine
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.db import windows as window_db
from app.db.changes import ChangeFeed, horizon, prune
from app.db.entries import ClipEntry, clip_entries
from app.db.migrate import upgrade
from app.db.session import create_db_engine, read_sessions, write_sessions
from app.errors import DescriptorOutdated, InvalidInput, StorageUnavailable
from app.index.catalogue import Catalogue
from app.index.index_set import IndexSet
from app.index.neighbour_scale import NeighbourScales
from app.index.places import WindowPlaces
from app.index.sources import (
    windows_of_clips,
)
from app.motion.descriptors import DEFAULT_DESCRIPTOR
from app.services import library_checks
from app.services.blobs import BlobStore, open_blob_store
from app.services.describe import (
    Describer,
    DescriptorInfo,
    MotionDescriber,
)
from app.services.export_pool import ExportPool
from app.services.library_caches import open_caches, window_keys
from app.services.library_places import load_places, save_places
from app.services.library_sync import DataVersion, sync_with_feed
from app.services.parser_pool import ParserPool

log = logging.getLogger(__name__)

# While a descriptor has outdated vectors, how often a search recounts them.
OUTDATED_RECOUNT_SECONDS = 5.0


def drop_clip_windows(library: Library, clip_ids: Sequence[int]) -> None:
    """Remove deleted clips' windows from this process's window indexes and places (the feed
    would, at the next sync; searches meanwhile skip windows without a row)."""
    clips = np.asarray(list(clip_ids), dtype=np.int64)
    for places in library.window_places.values():
        places.remove_clips(clips)
    for name, index in library.window_indexes.items():
        try:
            index.remove(windows_of_clips(index, clips))
        except OSError as exc:
            log.warning(
                "clips deleted, but the %s index could not be saved (%s); it is brought up "
                "to date from the database at the next start",
                name,
                exc,
            )


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
    # What a search shows of each clip (names, labels, ...): searches read no SQL.
    catalogue: Catalogue
    # Moments search: one index per window descriptor and length, keyed like window_keys.
    window_indexes: IndexSet = field(default_factory=lambda: IndexSet({}))
    window_keys: dict[str, window_db.WindowKey] = field(default_factory=dict)
    # Where each window of those indexes lies (moments search; loaded when first needed).
    window_places: dict[str, WindowPlaces] = field(default_factory=dict)
    # FBX/glTF readers' worker processes (started when first needed); None: those formats
    # cannot be read (a describer of the tests' own).
    parsers: ParserPool | None = None
    # FBX writers' worker processes (Blender; started when the first FBX is asked for).
    exporters: ExportPool | None = None
    write_lock: threading.Lock = field(default_factory=threading.Lock)
    # Renames, relabels and new notes made by this process: caches of names and labels
    # compare it (the catalogue follows the change feed, which has them since migration 0009).
    edits: int = 0
    # Each index's typical neighbour distances: the similarity of search results.
    scales: NeighbourScales = field(default_factory=NeighbourScales, repr=False)
    # Held while the caches follow the feed or are refilled (library_sync takes it too).
    sync_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    # Checks the checksums of the files mapped unchecked at start (verify_files).
    verifier: threading.Thread | None = field(default=None, repr=False)
    _refresher: threading.Thread | None = field(default=None, repr=False)
    _stopping: threading.Event = field(default_factory=threading.Event, repr=False)
    _refresher_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    # Descriptor -> stored vectors of an older version, and when that was last counted.
    _outdated: dict[str, int] = field(default_factory=dict, repr=False)
    _outdated_at: float = field(default=0.0, repr=False)
    # How far along the change feed the caches are (library_sync moves it).
    feed: ChangeFeed = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.window_places = {
            name: WindowPlaces(window_db.WINDOW_ID_BITS) for name in self.window_keys
        }
        # Every index is at least this far along the feed (they were loaded from one snapshot).
        positions = [i.synced_to for i in self.indexes.values()] + [self.catalogue.synced_to]
        self.feed = ChangeFeed(min(positions))

    @property
    def descriptors(self) -> Mapping[str, DescriptorInfo]:
        return self.describer.descriptors

    @property
    def default_descriptor(self) -> str:
        """The descriptor a search uses when none is named: ``motion`` (the best all-round
        one) when the describer has it, else the describer's first."""
        if DEFAULT_DESCRIPTOR in self.descriptors:
            return DEFAULT_DESCRIPTOR
        return next(iter(self.descriptors))

    def count_outdated(self) -> dict[str, int]:
        """Descriptor -> how many stored vectors are of an older version (counted now)."""
        with self.reads() as session:
            counts = {
                name: vector_db.count_outdated_vectors(session, name, info.version)
                for name, info in self.descriptors.items()
            }
        self._outdated, self._outdated_at = counts, time.monotonic()
        return counts

    def require_current(self, name: str) -> None:
        """Refuse (409 ``descriptor_outdated``) a search under descriptor ``name`` while stored
        clips hold vectors of an older version of it — a library written by an earlier
        release: the search would silently miss them. Free once the library is current
        (counted at start; recounted at most every few seconds while it is not)."""
        if not self._outdated.get(name):
            return
        if time.monotonic() - self._outdated_at > OUTDATED_RECOUNT_SECONDS:
            self.count_outdated()
        outdated = self._outdated.get(name, 0)
        if outdated:
            version = self.descriptors[name].version
            raise DescriptorOutdated(
                f"{outdated} stored clips have {name!r} vectors of an older version than "
                f"{version} (written by an earlier release of mocap-index); stop the service "
                "and run `mocap-index reindex` to recompute them, or search with another "
                "descriptor"
            )

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
        with self.sync_lock, self.reads() as session:
            position = horizon(session)  # before the vectors: nothing older is missed
            ids, vectors = vector_db.load_vectors(session, info.name, info.version, info.dimension)
            self.indexes[name].replace_all(ids, vectors, synced_to=position)
        self.scales.forget(name)  # it may have been measured on a damaged file

    def rebuild_window_indexes(self, names: Collection[str] | None = None) -> None:
        """Refill every window index (or those ``names``) from the database and save it."""
        with self.sync_lock, self.reads() as session:
            position = horizon(session)  # before the vectors: nothing older is missed
            for name, key in self.window_keys.items():
                if names is not None and name not in names:
                    continue
                ids, vectors = window_db.load_windows(session, key)
                self.window_indexes[name].replace_all(ids, vectors, synced_to=position)
                self.scales.forget(name)  # it may have been measured on a damaged file
                if self.window_places[name].loaded:
                    load_places(self, session, name)

    def clip_entry(self, clip_id: int) -> ClipEntry | None:
        """What a search shows of clip ``clip_id``: from the catalogue, or — a clip another
        process stored since the last look at the feed — from the database."""
        entry = self.catalogue.get(clip_id)
        if entry is not None:
            return entry
        with self.reads() as session:
            return next(clip_entries(session, [clip_id]), None)

    def rebuild_catalogue(self) -> None:
        """Refill the catalogue from the database and save it (after a bulk load that went
        around the feed's readers, like ``fill-synthetic``)."""
        with self.sync_lock, self.reads() as session:
            position = horizon(session)  # before the rows: nothing older is missed
            self.catalogue.replace_all(clip_entries(session), synced_to=position)

    @property
    def stopping(self) -> bool:
        """Whether :meth:`close` has begun (background work stops at its next step)."""
        return self._stopping.is_set()

    def verify_files(self) -> list[str]:
        """Check the checksums left unchecked at start (``open_library(verify_later=True)``);
        rebuild from the database whatever fails. Returns what was rebuilt."""
        return library_checks.verify_files(self)

    def check_window_counts(self) -> list[str]:
        """Rebuild the window indexes when one's size disagrees with the database's windows
        (see :func:`app.services.library_checks.check_window_counts`). Returns those."""
        return library_checks.check_window_counts(self)

    def places(self, name: str) -> WindowPlaces:
        """Where the windows of window index ``name`` lie (loaded from the database when
        first asked for; then kept up to date with the index)."""
        places = self.window_places[name]
        if not places.loaded:
            with self.sync_lock, self.reads() as session:
                if not places.loaded:
                    load_places(self, session, name)
        return places

    def load_window_places(self) -> None:
        """Load every window index's places, and its sorted ids, now (the server, at
        start-up: its first moments search and its first upload are then as quick as the
        others)."""
        for name in self.window_keys:
            self.places(name)
            self.window_indexes[name].sorted_ids()

    def sync_indexes(self, *, wait: bool = True) -> bool:
        """Apply to the indexes the clips added or deleted since they last looked (by this
        process or another one). With ``wait=False`` it returns False at once when another
        thread is syncing (that thread brings the indexes up to date)."""
        return sync_with_feed(self, wait=wait)

    def prune_changes(self) -> int:
        """Delete the change rows older than ``MOCAP_CHANGE_RETENTION_HOURS`` (and record
        where the feed stands now, for a later prune); returns how many went."""
        retention = timedelta(hours=self.settings.change_retention_hours)
        with self.write_lock, self.writes.begin() as session:
            return prune(session, retention)

    def start_housekeeping(self) -> None:
        """Prune the change feed now and then in a thread of its own (a server's), about
        eight times per retention, at least hourly; stopped by :meth:`close`."""
        every = min(3600.0, self.settings.change_retention_hours * 3600 / 8)

        def run() -> None:
            while True:
                try:
                    removed = self.prune_changes()
                except (SQLAlchemyError, sqlite3.Error) as exc:
                    log.warning("could not prune the change feed: %s", exc)
                else:
                    if removed:
                        log.info("pruned %d change feed rows older than the retention", removed)
                if self._stopping.wait(every):
                    return

        threading.Thread(target=run, name="mocap-housekeeping", daemon=True).start()

    def refresh(self) -> None:
        """Keep the indexes up to date with the database, within
        ``MOCAP_INDEX_REFRESH_SECONDS`` (called before searches). With 0, check now; else a
        thread of the library checks that often (started at the service's start, or here the
        first time), so no search waits for the database. Starting it checks once first: a
        process that has not searched yet must not answer from what it loaded at start."""
        interval = self.settings.index_refresh_seconds
        if interval <= 0:
            self._check()
            return
        if self._refresher is None:
            with self._refresher_lock:
                if self._refresher is None and not self._stopping.is_set():
                    self._check()
                    self._refresher = threading.Thread(
                        target=self._refresh_loop, args=(interval,), daemon=True
                    )
                    self._refresher.start()

    def refresh_now(self) -> None:
        """Bring the indexes up to date with the database now, waiting for a sync already
        under way (``/health``: what it reports includes every change committed before)."""
        try:
            self.sync_indexes()
        except (SQLAlchemyError, sqlite3.Error) as exc:  # the indexes as they are still work
            log.warning("could not check the database for changed clips: %s", exc)

    def _refresh_loop(self, interval: float) -> None:
        watch = DataVersion(self.engine)
        try:
            while True:
                if watch.changed():
                    self._check()
                if self._stopping.wait(interval):
                    return
        finally:
            watch.close()

    def _check(self) -> None:
        try:
            self.sync_indexes(wait=False)
        except (SQLAlchemyError, sqlite3.Error) as exc:  # the indexes as they are still work
            log.warning("could not check the database for changed clips: %s", exc)
        except Exception:  # never let the refresher die
            log.exception("checking the database for changed clips failed")

    def save_indexes(self) -> None:
        """Write the indexes that have unsaved changes (large ones are not saved after every
        change; a file that is behind is brought up to date from the database when loaded)."""
        self.indexes.save(only_changed=True)
        self.window_indexes.save(only_changed=True)
        self.catalogue.flush()
        for name, places in self.window_places.items():
            if places.loaded and places.changed:
                save_places(self, name, self.feed.position)

    def vector_counts(self) -> tuple[int, dict[str, int]]:
        """The number of clips and, per descriptor, of current vectors (one snapshot)."""
        with self.reads() as session:
            clips = clip_db.count_clips(session)
            return clips, {
                name: vector_db.count_vectors(session, name, info.version)
                for name, info in self.descriptors.items()
            }

    def clip_count(self) -> int:
        with self.reads() as session:
            return clip_db.count_clips(session)

    def close(self) -> None:
        self._stopping.set()
        if self.verifier is not None:
            self.verifier.join(timeout=60)
        if self._refresher is not None:
            self._refresher.join(timeout=30)
        try:
            self.save_indexes()
        finally:
            self.engine.dispose()
            if self.parsers is not None:
                self.parsers.close()
            if self.exporters is not None:
                self.exporters.close()


def open_library(
    settings: Settings, *, describer: Describer | None = None, verify_later: bool = False
) -> Library:
    """Migrate the database to the newest schema and load (or rebuild) the indexes.

    ``verify_later`` (the server): the large, mapped files are used before their checksums
    are checked, and the window indexes before their sizes are compared with the database;
    a thread of the library checks both (:meth:`Library.check_window_counts`,
    :meth:`Library.verify_files`) and rebuilds what fails, so a server answers within seconds
    of starting at a million clips (hashing them was most of the start)."""
    parsers = ParserPool.from_settings(settings)  # no process until an FBX/glTF arrives
    if describer is None:
        describer = MotionDescriber.from_settings(settings, parsers=parsers)
    if not describer.descriptors:
        raise RuntimeError("the describer offers no descriptor")
    try:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        engine = create_db_engine(settings.sqlalchemy_url, synchronous=settings.sqlite_synchronous)
        upgrade(engine)
    except (OSError, SQLAlchemyError) as exc:
        parsers.close()
        raise StorageUnavailable(f"cannot open the database: {exc}") from exc
    reads = read_sessions(engine)
    try:
        indexes, windows, catalogue = open_caches(
            settings, reads, describer.descriptors, verify=not verify_later
        )
        with reads() as session:
            clips = clip_db.count_clips(session)
    except BaseException:
        engine.dispose()
        parsers.close()
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
    library = Library(
        settings=settings,
        engine=engine,
        reads=reads,
        writes=write_sessions(engine),
        blobs=open_blob_store(engine, settings.files_dir),
        indexes=indexes,
        describer=describer,
        catalogue=catalogue,
        window_indexes=windows,
        window_keys=window_keys(settings, describer.descriptors),
        parsers=parsers,
        exporters=ExportPool.from_settings(settings),  # no process until an FBX is asked for
    )
    if verify_later:
        library.verifier = threading.Thread(
            target=library_checks.check_files, args=(library,), name="verify-files", daemon=True
        )
        library.verifier.start()
    for name, outdated in library.count_outdated().items():
        if outdated:
            log.warning(
                "%d clips have %r vectors of an older version: searches under %r answer 409 "
                "until `mocap-index reindex` recomputes them",
                outdated,
                name,
                name,
            )
    return library
