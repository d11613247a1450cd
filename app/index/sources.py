"""The database's view of what an in-memory cache holds: the snapshot it is loaded, checked
and repaired against (:class:`~app.index.descriptor_index.VectorSource`,
:class:`~app.index.catalogue.ClipSource`), for clip indexes (one descriptor's vectors, ids =
clip ids), window indexes (one descriptor's windows of one length, ids = window ids ``clip id
<< WINDOW_ID_BITS | ordinal``) and the catalogue (every clip's display data)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np
from sqlalchemy.orm import Session

from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.db import windows as window_db
from app.db.changes import read_since
from app.db.entries import ClipEntry, clip_entries
from app.index.descriptor_index import DescriptorIndex
from app.index.places import rows_of_clips

if TYPE_CHECKING:  # the index package does not depend on the services
    from app.services.describe import DescriptorInfo


class StoredVectors:
    """One descriptor's vectors in the database, read in ``session``, with the change feed
    position ``watermark`` taken before them: what :meth:`DescriptorIndex.load_or_rebuild`
    checks an index against."""

    def __init__(self, session: Session, info: DescriptorInfo, watermark: int) -> None:
        self._session = session
        self._info = info
        self._watermark = watermark

    def watermark(self) -> int:
        return self._watermark

    def count(self) -> int:
        return vector_db.count_vectors(self._session, self._info.name, self._info.version)

    def ids(self) -> np.ndarray:
        info = self._info
        return vector_db.vector_ids(self._session, info.name, info.version, info.dimension)

    def vectors(self) -> tuple[np.ndarray, np.ndarray]:
        info = self._info
        return vector_db.load_vectors(self._session, info.name, info.version, info.dimension)

    def changed(self, since: int) -> np.ndarray:
        rows = read_since(self._session, since)[1]
        return np.unique(np.fromiter((r.clip_id for r in rows), dtype=np.int64, count=len(rows)))

    def vectors_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        info = self._info
        return vector_db.load_vectors_of(
            self._session, info.name, info.version, info.dimension, ids.tolist()
        )


class StoredWindows:
    """One window index's vectors in the database (see :class:`StoredVectors`); ids are
    window ids, ``watermark`` the change feed position taken before them. The feed names
    clips: a changed clip's windows are those ``index`` holds under its id plus those the
    database holds (a clip's window ids are ``clip id << WINDOW_ID_BITS | ordinal``)."""

    def __init__(
        self, session: Session, key: window_db.WindowKey, watermark: int, index: DescriptorIndex
    ) -> None:
        self._session = session
        self._key = key
        self._watermark = watermark
        self._index = index

    def watermark(self) -> int:
        return self._watermark

    def count(self) -> int:
        return window_db.count_windows(self._session, self._key)

    def ids(self) -> np.ndarray:
        return window_db.window_ids(self._session, self._key)

    def vectors(self) -> tuple[np.ndarray, np.ndarray]:
        return window_db.load_windows(self._session, self._key)

    def changed(self, since: int) -> np.ndarray:
        rows = read_since(self._session, since)[1]
        clips = np.unique(np.fromiter((r.clip_id for r in rows), dtype=np.int64, count=len(rows)))
        stored = window_db.window_ids_of_clips(self._session, self._key, clips.tolist())
        return touched_windows(self._index, clips, stored)

    def vectors_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return window_db.load_windows_of(self._session, self._key, ids.tolist())


def windows_of_clips(index: DescriptorIndex, clip_ids: np.ndarray) -> np.ndarray:
    """``(N,)`` int64 ids of the windows ``index`` holds of the clips ``clip_ids`` (a binary
    search each in the index's sorted ids: a clip's ids are ``clip id << WINDOW_ID_BITS |
    ordinal``)."""
    if not len(clip_ids) or not index.size:
        return np.zeros(0, dtype=np.int64)
    held = index.sorted_ids()
    clips = np.unique(np.asarray(clip_ids, dtype=np.int64))
    return held[rows_of_clips(held, clips, window_db.WINDOW_ID_BITS)[0]]


def touched_windows(index: DescriptorIndex, clip_ids: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """The window ids to check when the clips ``clip_ids`` changed: those ``index`` holds of
    them and ``stored`` ``(N,)``, those the database holds now."""
    return np.union1d(windows_of_clips(index, clip_ids), stored)


class StoredClips:
    """The clips in the database, read in ``session``, with the change feed position
    ``watermark`` taken before them: what :meth:`Catalogue.load_or_rebuild` checks the
    catalogue against."""

    def __init__(self, session: Session, watermark: int) -> None:
        self._session = session
        self._watermark = watermark

    def watermark(self) -> int:
        return self._watermark

    def count(self) -> int:
        return clip_db.count_clips(self._session)

    def ids(self) -> np.ndarray:
        return np.asarray(clip_db.all_clip_ids(self._session), np.int64)

    def entries(self) -> Iterator[ClipEntry]:
        return clip_entries(self._session)

    def changed(self, since: int) -> np.ndarray:
        rows = read_since(self._session, since)[1]
        return np.unique(np.fromiter((r.clip_id for r in rows), dtype=np.int64, count=len(rows)))

    def entries_of(self, ids: np.ndarray) -> dict[int, ClipEntry]:
        return {entry.id: entry for entry in clip_entries(self._session, ids.tolist())}
