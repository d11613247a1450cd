"""Following the change feed: the library's caches (every clip index, the window indexes and
their places, the catalogue) brought up to date with the database, the source of truth.

:func:`sync_with_feed` applies the clips added or deleted since the caches last looked, by
this process or another one (:mod:`app.db.changes`); a process away longer than the feed
keeps its rows rebuilds them all. :class:`app.services.library.Library` calls it after its
own writes and from its refresher, which asks :class:`DataVersion` whether a SQLite
database changed at all before it polls.
"""

from __future__ import annotations

import logging
import sqlite3
from typing import TYPE_CHECKING

import numpy as np
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from app.db import vectors as vector_db
from app.db import windows as window_db
from app.db.changes import ChangeFeed, horizon, pruned_before
from app.db.entries import clip_entries
from app.index.places import Places
from app.index.sources import touched_windows
from app.services.library_places import load_places
from app.services.preview_store import preview_store

if TYPE_CHECKING:
    from app.services.library import Library

log = logging.getLogger(__name__)


def sync_with_feed(library: Library, *, wait: bool = True) -> bool:
    """Apply to the indexes the clips added or deleted since they last looked (by this
    process or another one). With ``wait=False`` it returns False at once when another
    thread is syncing (that thread brings the indexes up to date)."""
    if not library.sync_lock.acquire(blocking=wait):
        return False
    try:
        with library.reads() as session:
            if library.feed.position < pruned_before(session):
                rebuild_all(library, session)  # away longer than the feed keeps its rows
                return True
            poll = library.feed.poll(session)
            changed = poll.clip_ids
            if not changed.size:  # the usual poll: nothing to look up or lock
                for index in (*library.indexes.values(), *library.window_indexes.values()):
                    index.mark_synced(poll.position)
                library.catalogue.mark_synced(poll.position)
                library.feed.advance(poll)
                return True
            # The catalogue first: a hit an index finds always has its display data.
            sync_catalogue(library, session, changed, poll.position)
            for name, info in library.descriptors.items():
                index = library.indexes[name]
                ids, vectors = vector_db.load_vectors_of(
                    session, info.name, info.version, info.dimension, changed.tolist()
                )
                try:
                    index.apply_changes(changed, ids, vectors, synced_to=poll.position)
                except Exception:
                    # The rows are committed; the index is only a cache of them.
                    log.exception("updating the %s index failed; rebuilding it", name)
                    position = horizon(session)
                    everything = vector_db.load_vectors(
                        session, info.name, info.version, info.dimension
                    )
                    index.replace_all(*everything, synced_to=position, persist=False)
                    index.try_save()
            sync_windows(library, session, changed, poll.position)
            library.feed.advance(poll)
    finally:
        library.sync_lock.release()
    return True


def sync_catalogue(library: Library, session: Session, changed: np.ndarray, position: int) -> None:
    """The catalogue follows the same feed: a changed clip's entry is replaced by what the
    database holds now (none when it was deleted). A clip deleted by another process also
    loses the previews this process stored of it (its motion does not stay on disk)."""
    try:
        entries = {e.id: e for e in clip_entries(session, changed.tolist())}
        gone = [int(i) for i in changed.tolist() if int(i) not in entries]
        was = library.catalogue.get_many(gone) if gone else {}
        library.catalogue.apply_changes(changed, entries, synced_to=position)
    except Exception:
        log.exception("updating the catalogue failed; rebuilding it")
        now = horizon(session)
        library.catalogue.replace_all(clip_entries(session), synced_to=now, persist=False)
        library.catalogue.try_save()
        return
    kept = {e.content_hash for e in entries.values()}  # the same content stored again
    forget_previews(library, [e.content_hash for e in was.values() if e.content_hash not in kept])


def forget_previews(library: Library, content_hashes: list[str]) -> None:
    """Remove this process's stored previews of clips deleted elsewhere (the deleting
    process removed its own; on a shared data directory this finds nothing left)."""
    if not content_hashes:
        return
    try:
        preview_store(library.settings).remove(content_hashes)
    except OSError as exc:
        log.warning("the stored previews of %d deleted clips stay (%s)", len(content_hashes), exc)


def sync_windows(library: Library, session: Session, changed: np.ndarray, position: int) -> None:
    """The window indexes follow the same feed: a changed clip's windows are replaced
    by those the database holds now (none when it was deleted)."""
    for name, key in library.window_keys.items():
        index = library.window_indexes[name]
        try:
            ids, vectors = window_db.load_windows_of_clips(session, key, changed.tolist())
            touched = touched_windows(index, changed, ids)
            index.apply_changes(touched, ids, vectors, synced_to=position)
            places = library.window_places[name]
            if places.loaded and changed.size:
                found = window_db.window_places_of_clips(session, key, changed.tolist())
                places.apply_changes(changed, Places(*found))
        except Exception:
            log.exception("updating the %s index failed; rebuilding it", name)
            now = horizon(session)  # not ``position``: the other indexes keep the poll's
            everything = window_db.load_windows(session, key)
            index.replace_all(*everything, synced_to=now, persist=False)
            index.try_save()
            if library.window_places[name].loaded:
                load_places(library, session, name)


def rebuild_all(library: Library, session: Session) -> None:
    """Refill every index from the database and follow the feed from now on (the caller
    holds the sync lock): the change rows this process had not read yet were pruned."""
    position = horizon(session)  # before the vectors: nothing older is missed
    log.warning(
        "the change feed no longer holds the changes since this process last looked "
        "(away longer than MOCAP_CHANGE_RETENTION_HOURS): rebuilding the indexes"
    )
    # The catalogue first: a hit an index finds always has its display data.
    library.catalogue.replace_all(clip_entries(session), synced_to=position, persist=False)
    library.catalogue.try_save()
    for name, info in library.descriptors.items():
        everything = vector_db.load_vectors(session, info.name, info.version, info.dimension)
        library.indexes[name].replace_all(*everything, synced_to=position, persist=False)
        library.indexes[name].try_save()
    for name, key in library.window_keys.items():
        everything = window_db.load_windows(session, key)
        library.window_indexes[name].replace_all(*everything, synced_to=position, persist=False)
        library.window_indexes[name].try_save()
        if library.window_places[name].loaded:
            load_places(library, session, name)
    library.feed = ChangeFeed(position)
    sweep_previews(library)  # the feed's rows of deleted clips are gone: compare contents


def sweep_previews(library: Library) -> None:
    """Remove the stored previews whose content no clip in the catalogue has."""
    try:
        stored = preview_store(library.settings).stored_hashes()
    except OSError as exc:
        log.warning("cannot list the stored previews (%s)", exc)
        return
    if stored:
        kept = {e.content_hash for e in library.catalogue.entries() if e.content_hash in stored}
        forget_previews(library, sorted(stored - kept))


class DataVersion:
    """Whether a SQLite database may have changed since last asked: ``PRAGMA data_version``
    on a connection of its own moves when another connection commits (no file read), so the
    refresher polls the feed only then — ten times a second a session and two statements
    cost an idle server a few per cent of a core. Other databases: always maybe."""

    def __init__(self, engine: Engine) -> None:
        self._connection: sqlite3.Connection | None = None
        self._seen: int | None = None
        path = engine.url.database if engine.dialect.name == "sqlite" else None
        if path:
            try:
                self._connection = sqlite3.connect(path, check_same_thread=False)
            except sqlite3.Error:
                self._connection = None

    def changed(self) -> bool:
        if self._connection is None:
            return True
        try:
            version = int(self._connection.execute("PRAGMA data_version").fetchone()[0])
        except sqlite3.Error:
            return True
        changed, self._seen = version != self._seen, version
        return changed

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()
