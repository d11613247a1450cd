"""k-nearest-neighbour search over one descriptor's index.

Distances are Euclidean (not squared). A search by a stored clip never returns that clip; a
search by an uploaded file excludes nothing. With a label, only clips carrying it are
searched — exactly, as FAISS skips the other ids while scanning. Several labels (or a
comma-separated one) keep the clips carrying all of them, compared case-insensitively. A
licence filter (:mod:`app.licences`) narrows the ids the same way: a filtered search is the
unfiltered ranking restricted to the clips the filters keep.

Each hit carries its ``similarity`` (:mod:`app.index.neighbour_scale`). With
``collapse=True`` one hit stands for each group of near-identical clips
(:mod:`app.services.captures`), listing the others (``others``), and near-identical copies
of a query clip are set aside (:attr:`ClipAnswer.query_others`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import vectors as vector_db
from app.db.entries import ClipEntry
from app.errors import DescriptorUnavailable, InvalidInput, NotFound
from app.labels import label_filter
from app.licences import LicenceArg, LicenceFilter, licence_filter
from app.services.captures import CaptureRule, group_nearest_first
from app.services.clips import MAX_ID
from app.services.ingest import describe, new_clip
from app.services.library import Library
from app.services.uploads import Upload

MAX_ATTEMPTS = 3


@dataclass(frozen=True, slots=True)
class Hit:
    clip: ClipEntry  # what a result shows of the clip, from the catalogue
    distance: float
    similarity: float = 100.0  # percent of the library's typical neighbour distances larger
    others: tuple[Hit, ...] = ()  # collapse: the near-identical clips this hit stands for


@dataclass(frozen=True)
class ClipAnswer:
    """``GET /search``: the query clip, its hits, and (collapse) its own near-identical
    copies, which are not among the hits."""

    clip: ClipEntry
    hits: list[Hit]
    query_others: list[Hit] = field(default_factory=list)


def check_k(library: Library, k: int) -> None:
    if not 1 <= k <= library.settings.max_k:
        raise InvalidInput(f"k: must be between 1 and {library.settings.max_k}, got {k}")


def allowed_clip_ids(
    library: Library, label: label_db.LabelFilter, licence: LicenceFilter
) -> np.ndarray | None:
    """``(N,)`` ids of the clips the label and licence filters keep (from the catalogue);
    ``None``: no filter."""
    catalogue = library.catalogue
    allowed = catalogue.ids_with_labels(label) if label_filter(label) else None
    if licence:
        licensed = catalogue.ids_matching("licence", licence.allows)
        allowed = licensed if allowed is None else np.intersect1d(allowed, licensed)
    return allowed


def capture_rule(library: Library) -> CaptureRule:
    versions = {name: info.version for name, info in library.descriptors.items()}
    return CaptureRule.of(library.indexes, versions)


def _nearest(
    library: Library,
    descriptor: str,
    vector: np.ndarray,
    k: int,
    *,
    label: label_db.LabelFilter,
    licence: LicenceFilter = LicenceFilter(),  # noqa: B008 - frozen, never changed
    exclude: int | None,
    collapse: bool = False,
) -> tuple[list[Hit], list[Hit]]:
    """The hits, read from the index and the catalogue (no SQL), and (collapse) the query
    clip's near-identical copies."""
    index = library.indexes[descriptor]
    catalogue = library.catalogue
    allowed = allowed_clip_ids(library, label, licence)
    also = [] if exclude is None else [exclude]
    rule = capture_rule(library) if collapse else None
    wanted = k if rule is None else 3 * k + 10
    groups: list[list[int]] = []
    for _ in range(MAX_ATTEMPTS + (8 if rule is not None else 0)):
        found = index.search(vector, wanted, allowed=allowed, exclude=exclude)
        clips = catalogue.get_many(found.ids.tolist())
        # Equal distances in id order: the same answer whatever FAISS's heap did.
        present = sorted(
            (
                (i, d)
                for i, d in zip(found.ids.tolist(), found.distances.tolist(), strict=True)
                if i in clips
            ),
            key=lambda hit: (hit[1], hit[0]),
        )
        exhausted = len(found) < wanted
        if rule is None:
            # A clip the index holds but the catalogue not (a sync between the two, which
            # follow the same feed one after the other) is skipped; ask for as many more as
            # went missing, so the answer still has k hits when the library does.
            if len(present) >= k or exhausted:
                break
            wanted += len(found) - len(present)
            continue
        ids = np.array([*also, *(i for i, _ in present)], np.int64)
        groups = group_nearest_first(ids.tolist(), rule.pairs(ids))
        shown = [g for g in groups if not (also and g[0] == 0)]
        # Complete once the k-th group's leader is nearer than the farthest hit by more
        # than a near-identical clip can lie beyond it.
        if exhausted or (
            len(shown) >= k
            and present[-1][1] >= present[shown[k - 1][0] - len(also)][1] + rule.reach(descriptor)
        ):
            break
        wanted *= 2
    if rule is None:
        present = present[:k]  # no similarity computed for hits not shown
    scale = library.scales.of(descriptor, index)
    similarity = scale.similarities([d for _, d in present])
    hits = [Hit(clips[i], d, s) for (i, d), s in zip(present, similarity, strict=True)]
    query_others: list[Hit] = []
    if rule is not None:
        offset = len(also)
        collapsed = []
        for group in groups:
            members = [hits[p - offset] for p in group if p >= offset]
            if also and group[0] == 0:
                query_others = members
                continue
            collapsed.append(dataclasses.replace(members[0], others=tuple(members[1:])))
        hits = collapsed
    return hits[:k], query_others


def search_vector(
    library: Library,
    descriptor: str,
    vector: np.ndarray,
    k: int,
    *,
    label: label_db.LabelFilter = None,
    licence: LicenceArg = None,
    exclude: int | None = None,
    collapse: bool = False,
) -> list[Hit]:
    """The ``k`` stored clips nearest to ``vector`` ``(D,)`` under ``descriptor``."""
    check_k(library, k)
    library.descriptor(descriptor)
    library.require_current(descriptor)
    library.refresh()
    return _nearest(
        library,
        descriptor,
        vector,
        k,
        label=label,
        licence=licence_filter(licence),
        exclude=exclude,
        collapse=collapse,
    )[0]


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
        # A clip deleted by another request between the catalogue's look-up and this read
        # is gone (404), not waiting for a reindex (409).
        if stored is None and clip_db.get_clip(session, clip_id) is None:
            raise NotFound(f"no clip with id {clip_id}")
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
    """The stored clip ``clip_id`` and its neighbours (never the clip itself). :class:`NotFound`
    when there is no such clip."""
    answer = find_by_clip(library, clip_id, descriptor, k, label=label)
    return answer.clip, answer.hits


def query_clip(
    library: Library, clip_id: int, descriptor: str, k: int
) -> tuple[ClipEntry, np.ndarray]:
    """The checks every search by a stored clip makes, then the clip and its ``descriptor``
    vector, shape ``(dims,)``. :class:`NotFound` when there is no such clip."""
    if not 0 < clip_id <= MAX_ID:  # no such id (and the database driver's overflow)
        raise NotFound(f"no clip with id {clip_id}")
    library.descriptor(descriptor)
    check_k(library, k)
    library.require_current(descriptor)
    library.refresh()
    clip = library.clip_entry(clip_id)
    if clip is None:
        raise NotFound(f"no clip with id {clip_id}")
    vector = clip_vector(library, clip_id, descriptor)
    return clip, vector


def find_by_clip(
    library: Library,
    clip_id: int,
    descriptor: str,
    k: int,
    *,
    label: label_db.LabelFilter = None,
    licence: LicenceArg = None,
    collapse: bool = False,
) -> ClipAnswer:
    """``GET /search``: the stored clip ``clip_id`` and its neighbours (never the clip
    itself), read from the indexes and the catalogue. :class:`NotFound` when there is no
    such clip."""
    clip, vector = query_clip(library, clip_id, descriptor, k)
    hits, query_others = _nearest(
        library,
        descriptor,
        vector,
        k,
        label=label,
        licence=licence_filter(licence),
        exclude=clip_id,
        collapse=collapse,
    )
    return ClipAnswer(clip, hits, query_others)


@dataclass(frozen=True, slots=True)
class PlainAnswer:
    """A search without filters or collapse (:func:`find_plain`): the query clip, and for
    each hit, nearest first, its id, distance, similarity and heading — the fields a hit
    shows, ``[name, format, filenames, skeleton_family, labels, ...]``
    (:meth:`app.index.catalogue.Catalogue.headings`)."""

    clip: ClipEntry
    ids: list[int]
    distances: list[float]
    similarities: list[float]
    headings: list[Sequence[Any]]


def find_plain(library: Library, clip_id: int, descriptor: str, k: int) -> PlainAnswer:
    """:func:`find_by_clip` without label, licence or collapse — what nearly every search
    asks — with the same hits, errors and checks, and less per-request work: the neighbours
    as Python numbers (:meth:`DescriptorIndex.nearest`), the hits' headings instead of
    their whole entries."""
    clip, vector = query_clip(library, clip_id, descriptor, k)
    found = library.indexes[descriptor].nearest(vector, k, exclude=clip_id)
    return plain_answer(library, clip, vector, descriptor, k, found)


def plain_answer(
    library: Library,
    clip: ClipEntry,
    vector: np.ndarray,
    descriptor: str,
    k: int,
    found: list[tuple[int, float]],
) -> PlainAnswer:
    """The rest of :func:`find_plain` from the index's neighbours ``found`` of the query
    clip's ``vector`` (searched here, or in the search lane: app/api/search_lane.py)."""
    index = library.indexes[descriptor]
    catalogue = library.catalogue
    wanted = k
    for attempt in range(MAX_ATTEMPTS):
        if attempt:
            found = index.nearest(vector, wanted, exclude=clip.id)
        headings = catalogue.headings([i for i, _ in found])
        # Equal distances in id order, as _nearest; a clip the catalogue does not hold yet is
        # skipped and as many more asked for (see _nearest).
        present = sorted(
            ((i, d) for i, d in found if i in headings), key=lambda hit: (hit[1], hit[0])
        )
        if len(present) >= k or len(found) < wanted:
            break
        wanted += len(found) - len(present)
    present = present[:k]
    distances = [d for _, d in present]
    return PlainAnswer(
        clip,
        [i for i, _ in present],
        distances,
        library.scales.of(descriptor, index).similarities(distances),
        [headings[i] for i, _ in present],
    )


def search_by_upload(
    library: Library,
    upload: Upload,
    descriptor: str,
    k: int,
    *,
    label: label_db.LabelFilter,
    licence: LicenceArg = None,
    collapse: bool = False,
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
    hits = search_vector(
        library, descriptor, vector, k, label=label, licence=licence, collapse=collapse
    )
    return query, hits


def stored_copy(library: Library, content_hash: str) -> clip_db.ClipRecord | None:
    """The stored clip with this content (an upload's), if any: "this file is clip #316"."""
    with library.reads() as session:
        return clip_db.get_clip_by_hash(session, content_hash)
