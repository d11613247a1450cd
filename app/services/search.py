"""k-nearest-neighbour search over one descriptor's index.

Distances are Euclidean (not squared). A search by a stored clip never returns that clip; a
search by an uploaded file excludes nothing. With a label, only clips carrying it are
searched — exactly, as FAISS skips the other ids while scanning. Several labels (or a
comma-separated one) keep the clips carrying all of them, compared case-insensitively.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import vectors as vector_db
from app.db.entries import ClipEntry
from app.errors import DescriptorUnavailable, InvalidInput, NotFound
from app.labels import label_filter
from app.services.ingest import describe, new_clip
from app.services.library import Library
from app.services.uploads import Upload

MAX_ATTEMPTS = 3


@dataclass(frozen=True, slots=True)
class Hit:
    clip: ClipEntry  # what a result shows of the clip, from the catalogue
    distance: float


def check_k(library: Library, k: int) -> None:
    if not 1 <= k <= library.settings.max_k:
        raise InvalidInput(f"k: must be between 1 and {library.settings.max_k}, got {k}")


def _nearest(
    library: Library,
    descriptor: str,
    vector: np.ndarray,
    k: int,
    *,
    label: label_db.LabelFilter,
    exclude: int | None,
) -> list[Hit]:
    """The hits, read from the index and the catalogue (no SQL)."""
    index = library.indexes[descriptor]
    catalogue = library.catalogue
    allowed = catalogue.ids_with_labels(label) if label_filter(label) else None
    wanted = k
    hits: list[Hit] = []
    for _ in range(MAX_ATTEMPTS):
        found = index.search(vector, wanted, allowed=allowed, exclude=exclude)
        clips = catalogue.get_many(found.ids.tolist())
        hits = [
            Hit(clips[i], d)
            for i, d in zip(found.ids.tolist(), found.distances.tolist(), strict=True)
            if i in clips
        ]
        # A clip the index holds but the catalogue not (a sync between the two, which follow
        # the same feed one after the other) is skipped; ask for as many more as went
        # missing, so the answer still has k hits when the library does.
        if len(hits) >= k or len(found) < wanted:
            break
        wanted += len(found) - len(hits)
    return hits[:k]


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
    return _nearest(library, descriptor, vector, k, label=label, exclude=exclude)


def _unavailable(clip_id: int, descriptor: str, version: int) -> DescriptorUnavailable:
    return DescriptorUnavailable(
        f"clip {clip_id} has no {descriptor!r} vector of version {version} yet; "
        "run `mocap-index reindex`"
    )


def clip_vector(library: Library, clip_id: int, descriptor: str) -> np.ndarray:
    """The stored ``descriptor`` vector ``(D,)`` of clip ``clip_id``: from its index, or
    (a clip the index does not hold yet) from the database."""
    try:
        return library.indexes[descriptor].reconstruct(clip_id)
    except KeyError:
        pass
    info = library.descriptors[descriptor]
    with library.reads() as session:
        stored = vector_db.get_vector(session, clip_id, descriptor)
    if stored is None or stored.version != info.version or stored.vector.size != info.dimension:
        raise _unavailable(clip_id, descriptor, info.version)
    return stored.vector


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
) -> tuple[ClipEntry, list[Hit]]:
    """The stored clip ``clip_id`` and its neighbours (never the clip itself): ``GET
    /search``. :class:`NotFound` when there is no such clip."""
    library.descriptor(descriptor)
    check_k(library, k)
    library.require_current(descriptor)
    library.refresh()
    clip = library.clip_entry(clip_id)
    if clip is None:
        raise NotFound(f"no clip with id {clip_id}")
    vector = clip_vector(library, clip_id, descriptor)
    return clip, _nearest(library, descriptor, vector, k, label=label, exclude=clip_id)


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
