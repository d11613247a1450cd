"""What a server's verifier thread checks after start (``open_library(verify_later=True)``:
the files were mapped unchecked so a start is quick): the clip indexes' search decisions and
every index's similarity scale first (a search may come soon), the window indexes' sizes
against the database, then the files' checksums; whatever disagrees is rebuilt from the
database, the source of truth."""

from __future__ import annotations

import logging
import sqlite3
from typing import TYPE_CHECKING

from sqlalchemy.exc import SQLAlchemyError

from app.db import windows as window_db

if TYPE_CHECKING:
    from app.services.library import Library

log = logging.getLogger(__name__)


def verify_files(library: Library) -> list[str]:
    """Check the checksums left unchecked at start (``open_library(verify_later=True)``);
    rebuild from the database whatever fails. Returns what was rebuilt."""
    rebuilt = []
    for name, index in library.indexes.items():
        problem = index.verify_file()
        if problem is not None and not library.stopping:
            log.warning("rebuilding the %s index from the database: %s", name, problem)
            library.rebuild_index(name)
            rebuilt.append(name)
    for name, index in library.window_indexes.items():
        problem = index.verify_file()
        if problem is not None and not library.stopping:
            log.warning("rebuilding the %s index from the database: %s", name, problem)
            library.rebuild_window_indexes()
            rebuilt.append(name)
    problem = library.catalogue.verify_file()
    if problem is not None and not library.stopping:
        log.warning("rebuilding the catalogue from the database: %s", problem)
        library.rebuild_catalogue()
        rebuilt.append("catalogue")
    return rebuilt


def check_window_counts(library: Library) -> list[str]:
    """Compare each window index's size with the windows the database holds for it, at
    one feed position, and rebuild the window indexes when one disagrees (what
    :meth:`DescriptorIndex.load_or_rebuild` checks at start; a server, opened with
    ``verify_later``, checks it here, in its verifier thread: counting 1.7 M rows per
    index at 100 hours was a large part of a start). Returns the indexes that disagreed."""
    for _ in range(3):  # until no change arrives between the sync and the counts
        library.sync_indexes()
        # Counted without the sync lock (a start's loading of the places waits for it):
        # the counts hold if the indexes followed no change meanwhile.
        with library.reads() as session:
            seen = library.feed.position
            if library.feed.poll(session).clip_ids.size:
                continue  # changed meanwhile: sync again
            counts = {
                name: window_db.count_windows(session, key)
                for name, key in library.window_keys.items()
            }
        sizes = {name: library.window_indexes[name].size for name in counts}
        if library.feed.position != seen:
            continue
        wrong = [name for name in counts if counts[name] != sizes[name]]
        if wrong and not library.stopping:
            log.warning(
                "the window indexes %s disagree with the database's windows: rebuilding",
                ", ".join(wrong),
            )
            library.rebuild_window_indexes(wrong)
        return wrong
    return []


def check_files(library: Library) -> None:
    """The verifier thread of a server: the clip indexes' search decisions and every
    index's similarity scale (first: a search may come soon; see
    :meth:`HeldIndex.prepare_searches`, :meth:`NeighbourScales.of`), window counts,
    then checksums (see :func:`check_window_counts`, :func:`verify_files`)."""
    for name, index in library.indexes.items():
        if not library.stopping:
            index.prepare_searches()
            library.scales.of(name, index)
    for name, index in library.window_indexes.items():
        if not library.stopping:
            library.scales.of(name, index, window_db.clips_of_windows)
    try:
        library.check_window_counts()
    except (SQLAlchemyError, sqlite3.Error) as exc:
        log.warning("could not count the windows in the database: %s", exc)
    library.verify_files()
