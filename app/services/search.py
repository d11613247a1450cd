"""k-nearest-neighbour search over one descriptor's index.

Distances are Euclidean (not squared). A search by a stored clip never returns that clip; a
search by an uploaded file excludes nothing. With a label, only clips carrying it are
searched — exactly, as FAISS skips the other ids while scanning.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.db import repository as repo
from app.errors import InvalidInput, MocapError
from app.services.ingest import describe, new_clip
from app.services.library import Library
from app.services.uploads import Upload

MAX_ATTEMPTS = 3


class DescriptorUnavailable(MocapError):
    """The query clip has no vector of the descriptor's current version (the descriptor is
    newer than the clip); ``mocap-index reindex`` computes it.

    Belongs in ``app/errors.py``; kept here until that file is changed.
    """

    code = "descriptor_unavailable"


@dataclass(frozen=True)
class Hit:
    clip: repo.ClipRecord
    distance: float


def check_k(library: Library, k: int) -> None:
    if not 1 <= k <= library.settings.max_k:
        raise InvalidInput(f"k: must be between 1 and {library.settings.max_k}, got {k}")


def search_vector(
    library: Library,
    descriptor: str,
    vector: np.ndarray,
    k: int,
    *,
    label: str | None = None,
    exclude: int | None = None,
) -> list[Hit]:
    """The ``k`` stored clips nearest to ``vector`` ``(D,)`` under ``descriptor``."""
    check_k(library, k)
    library.descriptor(descriptor)
    index = library.indexes[descriptor]
    allowed = None
    if label is not None:
        with library.reads() as session:
            allowed = repo.clip_ids_with_label(session, label)
    wanted = k
    for _ in range(MAX_ATTEMPTS):
        found = index.search(vector, wanted, allowed=allowed, exclude=exclude)
        with library.reads() as session:
            clips = repo.get_clips(session, found.ids.tolist())
        hits = [
            Hit(clips[int(i)], float(d))
            for i, d in zip(found.ids, found.distances, strict=True)
            if int(i) in clips
        ]
        # A clip deleted between the index search and the row lookup is skipped; ask for as
        # many more as went missing, so the answer still has k hits when the library does.
        if len(hits) >= k or len(found) < wanted:
            break
        wanted += len(found) - len(hits)
    return hits[:k]


def search_by_clip(
    library: Library, clip: repo.ClipRecord, descriptor: str, k: int, *, label: str | None
) -> list[Hit]:
    """Neighbours of a stored clip (never the clip itself)."""
    info = library.descriptor(descriptor)
    with library.reads() as session:
        stored = repo.get_vector(session, clip.id, descriptor)
    if stored is None or stored.version != info.version or stored.vector.size != info.dimension:
        raise DescriptorUnavailable(
            f"clip {clip.id} has no {descriptor!r} vector of version {info.version} yet; "
            "run `mocap-index reindex`"
        )
    return search_vector(library, descriptor, stored.vector, k, label=label, exclude=clip.id)


def search_by_upload(
    library: Library, upload: Upload, descriptor: str, k: int, *, label: str | None
) -> tuple[repo.NewClip, list[Hit]]:
    """Describe an upload without storing it and find its neighbours (nothing excluded).

    Returns what would be stored about the upload (no id) and the hits.
    """
    library.descriptor(descriptor)
    check_k(library, k)  # before the costly part
    described = describe(library, upload, only=[descriptor])
    query = new_clip(library, described)
    vector = query.vectors[descriptor].vector
    return query, search_vector(library, descriptor, vector, k, label=label)
