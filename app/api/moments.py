"""/search/moments: where in the stored clips a span of motion happens (moments search)."""

from __future__ import annotations

from typing import Annotated

import anyio
from fastapi import APIRouter, Query, Request, Response
from pydantic import BaseModel, ConfigDict, Field

from app.api import render
from app.api.deps import KQuery, LabelQuery, LibraryDep, UploadDep
from app.api.errors import error_responses
from app.api.offload import Offload
from app.api.schemas import ClipOut
from app.db import label_filters as label_db
from app.services import moments as moment_service
from app.services.library import Library

router = APIRouter(prefix="/search", tags=["search"])

DEFAULT_DESCRIPTOR = "motion"


class MomentOut(BaseModel):
    id: int = Field(description="Id of the clip the moment lies in.")
    name: str
    labels: list[str]
    format: str
    start: float = Field(description="Start of the moment, seconds from the file's first frame.")
    end: float = Field(description="End of the moment (exclusive), seconds.")
    distance: float = Field(
        description="How far the moment is from the query: the mean Euclidean distance of the "
        "clip's windows inside the moment to the query's own windows at the same offsets."
    )

    @classmethod
    def of(cls, moment: moment_service.Moment) -> MomentOut:
        return cls(
            id=moment.clip.id,
            name=moment.clip.name,
            labels=list(moment.clip.labels),
            format=moment.format,
            start=moment.start,
            end=moment.end,
            distance=moment.distance,
        )


class MomentQueryOut(BaseModel):
    clip: ClipOut | None = Field(description="The query clip; null for an uploaded file.")
    start: float = Field(description="Start of the query span, seconds from the file's start.")
    end: float = Field(description="End of the query span (exclusive), seconds.")


class MomentSearchResponse(BaseModel):
    """Moments nearest to the query span, nearest first."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "query": {"clip": None, "start": 1.0, "end": 3.5},
                    "descriptor": "motion",
                    "k": 1,
                    "results": [
                        {
                            "id": 12,
                            "name": "playground take 3",
                            "labels": ["jump"],
                            "format": "bvh",
                            "start": 41.2,
                            "end": 43.7,
                            "distance": 0.41,
                        }
                    ],
                }
            ]
        }
    )

    query: MomentQueryOut
    descriptor: str
    k: int
    results: list[MomentOut]


StartQuery = Annotated[
    float | None,
    Query(
        description="Start of the query span, seconds from the file's first frame (lead-in "
        "included); default: the clip's start."
    ),
]
EndQuery = Annotated[
    float | None,
    Query(description="End of the query span (exclusive), seconds; default: the clip's end."),
]
PerClipQuery = Annotated[
    int, Query(description="At most this many moments from one clip.", examples=[3])
]
MomentDescriptorQuery = Annotated[
    str, Query(description="Descriptor with windows to compare with.", examples=["motion"])
]
# A moments search reads the indexes and the catalogue (a few ms of Python), and may describe
# a span of a stored file: in a thread unless searches of its kind have been quick
# (app/api/offload.py), at most two at once (more only fight over the GIL on two cores).
MOMENTS = Offload(anyio.CapacityLimiter(2))


def _body(
    query: moment_service.MomentQuery,
    moments: list[moment_service.Moment],
    *,
    descriptor: str,
    k: int,
) -> bytes:
    return render.moment_search(
        query.clip,
        query.start,
        query.end,
        descriptor,
        k,
        [(m.clip, m.format, m.start, m.end, m.distance) for m in moments],
    )


def _by_clip(
    library: Library,
    clip: int,
    start: float | None,
    end: float | None,
    k: int,
    descriptor: str,
    label: label_db.LabelFilter,
    per_clip: int,
) -> bytes:
    query, moments = moment_service.search_moments_by_clip(
        library, clip, descriptor, start=start, end=end, k=k, per_clip=per_clip, label=label
    )
    return _body(query, moments, descriptor=descriptor, k=k)


@router.get(
    "/moments",
    summary="Moments like a span of a stored clip",
    response_model=MomentSearchResponse,
    responses=error_responses(404, 409, 422, 503),
)
async def search_moments_by_clip(
    request: Request,
    clip: Annotated[int, Query(description="Id of the query clip.", examples=[7])],
    start: StartQuery = None,
    end: EndQuery = None,
    k: KQuery = 10,
    descriptor: MomentDescriptorQuery = DEFAULT_DESCRIPTOR,
    label: LabelQuery = None,
    per_clip: PerClipQuery = 3,
) -> Response:
    """The `k` moments (spans of stored clips) nearest to the span [`start`, `end`) of clip
    `clip`, nearest first, at most `per_clip` from one clip; moments overlapping the query
    span itself are left out (other parts of the same clip may come back). Times are seconds
    from the first frame of the file as uploaded."""
    library: Library = request.app.state.library
    body = await MOMENTS.run(
        (descriptor, bool(label), start is not None or end is not None),
        lambda: _by_clip(library, clip, start, end, k, descriptor, label, per_clip),
    )
    return Response(body, media_type="application/json")


@router.post(
    "/moments",
    summary="Moments like a span of an uploaded file",
    response_model=MomentSearchResponse,
    responses=error_responses(400, 409, 413, 415, 422, 503),
)
def search_moments_by_upload(
    library: LibraryDep,
    upload: UploadDep,
    start: StartQuery = None,
    end: EndQuery = None,
    k: KQuery = 10,
    descriptor: MomentDescriptorQuery = DEFAULT_DESCRIPTOR,
    label: LabelQuery = None,
    per_clip: PerClipQuery = 3,
) -> Response:
    """Like `GET /search/moments`, the query being the span [`start`, `end`) of an uploaded
    file (same fields as `POST /clips`), which is stored nowhere; nothing is excluded."""
    query, moments = moment_service.search_moments_by_upload(
        library, upload, descriptor, start=start, end=end, k=k, per_clip=per_clip, label=label
    )
    return Response(
        _body(query, moments, descriptor=descriptor, k=k), media_type="application/json"
    )
