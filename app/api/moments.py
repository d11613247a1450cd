"""/search/moments: where in the stored clips a span of motion happens (moments search)."""

from __future__ import annotations

from typing import Annotated

import anyio
from fastapi import APIRouter, Query, Request, Response
from pydantic import BaseModel, ConfigDict, Field

from app.api import render
from app.api.deps import (
    ClipIdQuery,
    CollapseQuery,
    KQuery,
    LabelQuery,
    LibraryDep,
    LicenceQuery,
    UploadDep,
)
from app.api.errors import error_responses
from app.api.offload import Offload
from app.api.query_check import CheckedQueryRoute
from app.api.schemas import OTHERS_DOC, SIMILARITY_DOC, ClipOut, StoredClipRef
from app.db import label_filters as label_db
from app.services import moments as moment_service
from app.services.library import Library

router = APIRouter(prefix="/search", tags=["search"], route_class=CheckedQueryRoute)

DEFAULT_DESCRIPTOR = "motion"


class OtherMoment(BaseModel):
    """The same moment in a near-identical clip (``collapse=capture``)."""

    id: int
    name: str
    format: str
    start: float
    end: float
    distance: float


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
    similarity: float = Field(
        description=SIMILARITY_DOC.replace(
            "clips to its 10 nearest others",
            "windows of the query's window length to its 10 nearest windows of other clips",
        )
    )
    others: list[OtherMoment] | None = Field(
        default=None, exclude_if=lambda value: value is None, description=OTHERS_DOC
    )

    @classmethod
    def of(cls, moment: moment_service.Moment, *, collapsed: bool = False) -> MomentOut:
        return cls(
            id=moment.clip.id,
            name=moment.clip.name,
            labels=list(moment.clip.labels),
            format=moment.format,
            start=moment.start,
            end=moment.end,
            distance=moment.distance,
            similarity=moment.similarity,
            others=[
                OtherMoment(
                    id=o.clip.id,
                    name=o.clip.name,
                    format=o.format,
                    start=o.start,
                    end=o.end,
                    distance=o.distance,
                )
                for o in moment.others
            ]
            if collapsed
            else None,
        )


class MomentQueryOut(BaseModel):
    clip: ClipOut | None = Field(description="The query clip; null for an uploaded file.")
    start: float = Field(description="Start of the query span, seconds from the file's start.")
    end: float = Field(description="End of the query span (exclusive), seconds.")
    stored_clip: StoredClipRef | None = Field(
        default=None,
        description="An uploaded file already in the library (same content): that clip. Null "
        "otherwise (and for a query by a stored clip, which `clip` is).",
    )


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
                            "similarity": 88.5,
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
    collapsed: bool = False,
) -> bytes:
    return render.moment_search(query, descriptor, k, moments, collapsed=collapsed)


def _by_clip(
    library: Library,
    clip: int,
    start: float | None,
    end: float | None,
    k: int,
    descriptor: str,
    label: label_db.LabelFilter,
    per_clip: int,
    licence: list[str] | None = None,
    collapse: bool = False,
) -> bytes:
    query, moments = moment_service.search_moments_by_clip(
        library,
        clip,
        descriptor,
        start=start,
        end=end,
        k=k,
        per_clip=per_clip,
        label=label,
        licence=licence,
        collapse=collapse,
    )
    return _body(query, moments, descriptor=descriptor, k=k, collapsed=collapse)


@router.get(
    "/moments",
    summary="Moments like a span of a stored clip",
    response_model=MomentSearchResponse,
    responses=error_responses(404, 409, 422, 503),
)
async def search_moments_by_clip(
    request: Request,
    clip: ClipIdQuery,
    start: StartQuery = None,
    end: EndQuery = None,
    k: KQuery = 10,
    descriptor: MomentDescriptorQuery = DEFAULT_DESCRIPTOR,
    label: LabelQuery = None,
    per_clip: PerClipQuery = 3,
    licence: LicenceQuery = None,
    collapse: CollapseQuery = None,
) -> Response:
    """The `k` moments (spans of stored clips) nearest to the span [`start`, `end`) of clip
    `clip`, nearest first, at most `per_clip` from one clip; moments overlapping the query
    span itself are left out (other parts of the same clip may come back). Times are seconds
    from the first frame of the file as uploaded. The answer is the first `k` of one list
    whatever `k` and the filters: a larger `k` extends it, a `label` or `licence` filter
    restricts it to the clips kept. `collapse=capture`: one moment per place in a group of
    near-identical clips."""
    library: Library = request.app.state.library
    capture = collapse == "capture"
    body = await MOMENTS.run(
        (descriptor, bool(label) or bool(licence), capture, start is not None or end is not None),
        lambda: _by_clip(
            library, clip, start, end, k, descriptor, label, per_clip, licence, capture
        ),
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
    licence: LicenceQuery = None,
    collapse: CollapseQuery = None,
) -> Response:
    """Like `GET /search/moments`, the query being the span [`start`, `end`) of an uploaded
    file (same fields as `POST /clips`), which is stored nowhere; nothing is excluded. When
    the file is already stored, `query.stored_clip` names that clip."""
    capture = collapse == "capture"
    query, moments = moment_service.search_moments_by_upload(
        library,
        upload,
        descriptor,
        start=start,
        end=end,
        k=k,
        per_clip=per_clip,
        label=label,
        licence=licence,
        collapse=capture,
    )
    return Response(
        _body(query, moments, descriptor=descriptor, k=k, collapsed=capture),
        media_type="application/json",
    )
