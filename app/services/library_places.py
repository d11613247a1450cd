"""Where each window of the window indexes lies (:class:`app.index.places.WindowPlaces`, for
moments search): loaded from the places file when it can be followed from the change feed,
else from the database, and saved beside the indexes.

:class:`app.services.library.Library` loads a window index's places when first asked for
(:meth:`~app.services.library.Library.places`) and again when it rebuilds the index;
:mod:`app.services.library_sync` keeps them current with the feed.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np
from sqlalchemy.orm import Session

from app.db import windows as window_db
from app.db.changes import horizon, pruned_before, read_since
from app.index.array_file import read_arrays, write_arrays
from app.index.places import Places

if TYPE_CHECKING:
    from app.services.library import Library

log = logging.getLogger(__name__)

PLACES_FORMAT = 1  # the layout of a window index's places file


def load_places(library: Library, session: Session, name: str) -> None:
    """Fill ``library.window_places[name]`` (the caller holds the library's sync lock): from
    the places file when it can be used (mapped: shared by the server's processes), with the
    clips changed since it was written read again; else from the database, then saved.
    Changes after the indexes' feed position are applied again at the next sync (a clip's
    windows as a whole), so any later state is fine here."""
    places = library.window_places[name]
    found = read_arrays(library.settings.index_dir, f"{name}.places", {"format": PLACES_FORMAT})
    if not isinstance(found, str):
        arrays, meta = found
        loaded = Places(arrays["ids"], arrays["starts"], arrays["stops"])
        position = int(meta.get("feed_position", -1))
        # A file older than the feed keeps cannot be brought up to date from it.
        followable = pruned_before(session) <= position <= horizon(session)
        if len(loaded) == meta.get("count") and followable:
            changed = read_since(session, position)[1]
            clips = np.unique(np.fromiter((r.clip_id for r in changed), np.int64))
            places.replace_all(loaded)
            if clips.size:
                key = library.window_keys[name]
                found_rows = window_db.window_places_of_clips(session, key, clips.tolist())
                places.apply_changes(clips, Places(*found_rows))
            if len(places) == library.window_indexes[name].size:
                return
            log.warning(
                "the %s places hold %d windows, the index %d: reading them again",
                name,
                len(places),
                library.window_indexes[name].size,
            )
    position = horizon(session)  # before the rows: nothing older is missed
    places.replace_all(Places(*window_db.load_window_places(session, library.window_keys[name])))
    save_places(library, name, position)


def save_places(library: Library, name: str, position: int) -> None:
    """Write the places of window index ``name`` beside the index, with the feed
    ``position`` they follow (not saving them only costs a read from the database at the
    next start)."""
    held = library.window_places[name].held
    try:
        write_arrays(
            library.settings.index_dir,
            f"{name}.places",
            {"ids": held.ids, "starts": held.starts, "stops": held.stops},
            {"format": PLACES_FORMAT, "count": len(held), "feed_position": position},
        )
    except OSError as exc:
        log.warning("could not save the %s places (%s); read again at next start", name, exc)
