"""The hot routes' answers as JSON bytes in one orjson call (issue 23).

``GET /search`` and ``GET /search/moments`` are documented by their pydantic response models
(:mod:`app.api.schemas`, :mod:`app.api.moments`), but building eleven pydantic objects and
dumping them cost more than the search at a million clips. These functions give the same
bytes — same fields in the same order, the same float and date formatting (orjson and
pydantic-core both write the shortest repr and ``Z`` for UTC) — from plain dicts;
``tests/api/test_render.py`` checks them against the models on random records.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import orjson

from app.db.entries import ClipEntry

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


def hit_out(clip: ClipEntry, distance: float) -> dict[str, Any]:
    """:class:`app.api.schemas.SearchHit`."""
    return {
        "id": clip.id,
        "name": clip.name,
        "labels": clip.labels,
        "format": clip.format,
        "filenames": clip.filenames,
        "skeleton_family": clip.skeleton_family,
        "distance": distance,
    }


def clip_search(
    query: ClipEntry, descriptor: str, k: int, hits: Sequence[tuple[ClipEntry, float]]
) -> bytes:
    """:class:`app.api.schemas.ClipSearchResponse` as JSON."""
    return orjson.dumps(
        {
            "query": clip_out(query),
            "descriptor": descriptor,
            "k": k,
            "results": [hit_out(clip, distance) for clip, distance in hits],
        },
        option=OPTIONS,
    )


def moment_search(
    query: ClipEntry | None,
    start: float,
    end: float,
    descriptor: str,
    k: int,
    moments: Sequence[tuple[ClipEntry, str, float, float, float]],
) -> bytes:
    """:class:`app.api.moments.MomentSearchResponse` as JSON; ``moments`` are (clip,
    format, start, end, distance)."""
    return orjson.dumps(
        {
            "query": {
                "clip": None if query is None else clip_out(query),
                "start": start,
                "end": end,
            },
            "descriptor": descriptor,
            "k": k,
            "results": [
                {
                    "id": clip.id,
                    "name": clip.name,
                    "labels": clip.labels,
                    "format": fmt,
                    "start": first,
                    "end": last,
                    "distance": distance,
                }
                for clip, fmt, first, last, distance in moments
            ],
        },
        option=OPTIONS,
    )
