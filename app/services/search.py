"""k-nearest-neighbour search over one descriptor's index.

Distances are Euclidean (not squared). A search by a stored clip never returns that clip; a
search by an uploaded file excludes nothing. With a label, only clips carrying it are
searched — exactly, as FAISS skips the other ids while scanning. Several labels (or a
comma-separated one) keep the clips carrying all of them, compared case-insensitively.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import search_reads as search_db
from app.errors import DescriptorUnavailable, InvalidInput, NotFound
from app.labels import label_filter
from app.services.clips import MAX_ID
from app.services.ingest import describe, new_clip
from app.services.library import Library
from app.services.uploads import Upload

MAX_ATTEMPTS = 3


@dataclass(frozen=True, slots=True)
class Hit:
    clip: search_db.ClipName  # id, name and labels (a ClipRecord has them too)
    distance: float


QUICK_SCAN = 1_000_000  # numbers compared per query below which a search is "quick"
QUICK_K = 100


def is_quick(library: Library, descriptor: str, k: int, label: label_db.LabelFilter) -> bool:
    """Whether a search by clip takes well under a millisecond (an unfiltered search that
    compares at most :data:`QUICK_SCAN` numbers and fetches at most :data:`QUICK_K` rows), so
    a caller may run it without handing it to a thread. Unknown descriptors count as quick
    (they fail at once). Never on a database server (PostgreSQL): its rows come over the
    network, and waiting for them must not hold up the event loop."""
    if library.engine.dialect.name != "sqlite":
        return False
    index = library.indexes.get(descriptor)
    if index is None:
        return True
    return not label_filter(label) and k <= QUICK_K and index.scan_cost() <= QUICK_SCAN


def check_k(library: Library, k: int) -> None:
    if not 1 <= k <= library.settings.max_k:
        raise InvalidInput(f"k: must be between 1 and {library.settings.max_k}, got {k}")


def _nearest(
    library: Library,
    db: search_db.SearchSnapshot,
    descriptor: str,
    vector: np.ndarray,
    k: int,
    *,
    label: label_db.LabelFilter,
    exclude: int | None,
) -> tuple[list[Hit], search_db.ClipName | None]:
    """The hits, and the name and labels of ``exclude`` (the query clip; fetched with the
    hits' to save a query)."""
    index = library.indexes[descriptor]
    allowed = db.clip_ids_with_label(label) if label_filter(label) else None
    also = [] if exclude is None else [exclude]
    wanted = k
    for _ in range(MAX_ATTEMPTS):
        found = index.search(vector, wanted, allowed=allowed, exclude=exclude)
        clips = db.names([*found.ids.tolist(), *also])
        hits = [
            Hit(clips[int(i)], float(d))
            for i, d in zip(found.ids, found.distances, strict=True)
            if int(i) in clips
        ]
        # A clip deleted (by another process) between the index search and the row lookup is
        # skipped; ask for as many more as went missing, so the answer still has k hits when
        # the library does.
        if len(hits) >= k or len(found) < wanted:
            break
        wanted += len(found) - len(hits)
    return hits[:k], None if exclude is None else clips.get(exclude)


def search_vector(
    library: Library,
    descriptor: str,
    vector: np.ndarray,
    k: int,
    *,
    label: label_db.LabelFilter = None,
    exclude: int | None = None,
) -> list[Hit]:
    """The ``k`` stored clips nearest to ``vector`` ``(D,)`` under ``descriptor``."""
    check_k(library, k)
    library.descriptor(descriptor)
    library.require_current(descriptor)
    library.refresh()
    with library.search_reads.snapshot() as db:
        return _nearest(library, db, descriptor, vector, k, label=label, exclude=exclude)[0]


def _unavailable(clip_id: int, descriptor: str, version: int) -> DescriptorUnavailable:
    return DescriptorUnavailable(
        f"clip {clip_id} has no {descriptor!r} vector of version {version} yet; "
        "run `mocap-index reindex`"
    )


def search_by_clip(
    library: Library,
    clip: clip_db.ClipRecord,
    descriptor: str,
    k: int,
    *,
    label: label_db.LabelFilter,
) -> list[Hit]:
    """Neighbours of a stored clip (never the clip itself)."""
    return search_by_clip_id(library, clip.id, descriptor, k, label=label)[1]


def search_by_clip_id(
    library: Library, clip_id: int, descriptor: str, k: int, *, label: label_db.LabelFilter
) -> tuple[clip_db.ClipRecord, list[Hit]]:
    """The stored clip ``clip_id`` and its neighbours (never the clip itself), read from one
    database snapshot: ``GET /search``. :class:`NotFound` when there is no such clip."""
    if not 0 < clip_id <= MAX_ID:  # no such id (and the database driver's overflow)
        raise NotFound(f"no clip with id {clip_id}")
    info = library.descriptor(descriptor)
    check_k(library, k)
    library.require_current(descriptor)
    library.refresh()
    with library.search_reads.snapshot() as db:
        clip = db.clip(clip_id, labels=False)
        if clip is None:
            raise NotFound(f"no clip with id {clip_id}")
        try:  # the index holds the clip's current vector: no need to read it
            vector = library.indexes[descriptor].reconstruct(clip_id)
        except KeyError:  # not in the index (yet): the database knows
            stored = db.vector(clip_id, descriptor)
            if (
                stored is None
                or stored.version != info.version
                or stored.vector.size != info.dimension
            ):
                raise _unavailable(clip_id, descriptor, info.version) from None
            vector = stored.vector
        hits, named = _nearest(library, db, descriptor, vector, k, label=label, exclude=clip_id)
        if named is None:  # deleted meanwhile by another process
            raise NotFound(f"no clip with id {clip_id}")
        clip = dataclasses.replace(clip, labels=named.labels)
    return clip, hits


def search_by_upload(
    library: Library, upload: Upload, descriptor: str, k: int, *, label: label_db.LabelFilter
) -> tuple[clip_db.NewClip, list[Hit]]:
    """Describe an upload without storing it and find its neighbours (nothing excluded).

    Returns what would be stored about the upload (no id) and the hits.
    """
    library.descriptor(descriptor)
    check_k(library, k)  # before the costly part
    library.require_current(descriptor)
    described = describe(library, upload, only=[descriptor])
    query = new_clip(library, described)
    vector = query.vectors[descriptor].vector
    return query, search_vector(library, descriptor, vector, k, label=label)
