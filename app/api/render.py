"""The hot routes' answers as JSON bytes in one orjson call (issue 23).

``GET /search`` and ``GET /search/moments`` are documented by their pydantic response models
(:mod:`app.api.schemas`, :mod:`app.api.moments`), but building eleven pydantic objects and
dumping them cost more than the search at a million clips. These functions give the same
bytes — same fields in the same order, the same float and date formatting (orjson and
pydantic-core both write the shortest repr and ``Z`` for UTC) — from plain dicts;
``tests/api/test_search_answers.py`` checks them against answers the models gave.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import orjson

from app.db.entries import ClipEntry

if TYPE_CHECKING:
    from app.services.moments import Moment, MomentQuery
    from app.services.search import Hit, PlainAnswer

OPTIONS = orjson.OPT_UTC_Z


def clip_out(clip: ClipEntry) -> dict[str, Any]:
    """:class:`app.api.schemas.ClipOut` of a stored clip (no descriptors, mapping or
    duplicate flag)."""
    fields: dict[str, Any] = {
        "name": clip.name,
        "filenames": clip.filenames,
        "format": clip.format,
        "content_hash": clip.content_hash,
        "frame_count": clip.frame_count,
        "frame_time": clip.frame_time,
        "duration": clip.duration,
        "joint_count": clip.joint_count,
        "skeleton_family": clip.skeleton_family,
        "lead_in_frames": clip.lead_in_frames,
        "warnings": clip.warnings,
        "labels": clip.labels,
        "source": clip.source,
        "licence": clip.licence,
    }
    if clip.animations is not None:
        fields["animations"] = [
            {
                "name": a.name,
                "frame_count": a.frame_count,
                "duration": a.duration,
                "selected": a.selected,
            }
            for a in clip.animations
        ]
    fields["id"] = clip.id
    fields["created_at"] = clip.created_at
    return fields


def hit_out(hit: Hit, collapsed: bool) -> dict[str, Any]:
    """:class:`app.api.schemas.SearchHit` (``others`` only when ``collapsed``)."""
    clip = hit.clip
    fields: dict[str, Any] = {
        "id": clip.id,
        "name": clip.name,
        "labels": clip.labels,
        "format": clip.format,
        "filenames": clip.filenames,
        "skeleton_family": clip.skeleton_family,
        "distance": hit.distance,
        "similarity": hit.similarity,
    }
    if collapsed:
        fields["others"] = [other_out(other) for other in hit.others]
    return fields


def other_out(hit: Hit) -> dict[str, Any]:
    """:class:`app.api.schemas.OtherFile`."""
    clip = hit.clip
    return {
        "id": clip.id,
        "name": clip.name,
        "format": clip.format,
        "filenames": clip.filenames,
        "distance": hit.distance,
    }


def clip_search(
    query: ClipEntry,
    descriptor: str,
    k: int,
    hits: Sequence[Hit],
    *,
    query_others: Sequence[Hit] | None = None,
) -> bytes:
    """:class:`app.api.schemas.ClipSearchResponse` as JSON; ``query_others`` (and each hit's
    ``others``) only for a collapsed search."""
    collapsed = query_others is not None
    body: dict[str, Any] = {
        "query": clip_out(query),
        "descriptor": descriptor,
        "k": k,
        "results": [hit_out(hit, collapsed) for hit in hits],
    }
    if query_others is not None:
        body["query_others"] = [other_out(other) for other in query_others]
    return orjson.dumps(body, option=OPTIONS)


def plain_clip_search(answer: PlainAnswer, descriptor: str, k: int) -> bytes:
    """:func:`clip_search` of a search without collapse, from its hits' headings
    (:func:`app.services.search.find_plain`): the same bytes."""
    results = [
        {
            "id": clip_id,
            "name": heading[0],
            "labels": heading[4],
            "format": heading[1],
            "filenames": heading[2],
            "skeleton_family": heading[3],
            "distance": distance,
            "similarity": similarity,
        }
        for clip_id, heading, distance, similarity in zip(
            answer.ids, answer.headings, answer.distances, answer.similarities, strict=True
        )
    ]
    body = {"query": clip_out(answer.clip), "descriptor": descriptor, "k": k, "results": results}
    return orjson.dumps(body, option=OPTIONS)


def moment_search(
    query: MomentQuery,
    descriptor: str,
    k: int,
    moments: Sequence[Moment],
    *,
    collapsed: bool = False,
) -> bytes:
    """:class:`app.api.moments.MomentSearchResponse` as JSON (each moment's ``others`` only
    when ``collapsed``)."""
    stored = query.stored_clip
    results = []
    for moment in moments:
        clip = moment.clip
        fields: dict[str, Any] = {
            "id": clip.id,
            "name": clip.name,
            "labels": clip.labels,
            "format": moment.format,
            "start": moment.start,
            "end": moment.end,
            "distance": moment.distance,
            "similarity": moment.similarity,
        }
        if collapsed:
            fields["others"] = [
                {
                    "id": other.clip.id,
                    "name": other.clip.name,
                    "format": other.format,
                    "start": other.start,
                    "end": other.end,
                    "distance": other.distance,
                }
                for other in moment.others
            ]
        results.append(fields)
    return orjson.dumps(
        {
            "query": {
                "clip": None if query.clip is None else clip_out(query.clip),
                "start": query.start,
                "end": query.end,
                "stored_clip": None if stored is None else {"id": stored.id, "name": stored.name},
            },
            "descriptor": descriptor,
            "k": k,
            "results": results,
        },
        option=OPTIONS,
    )
