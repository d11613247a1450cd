"""/search: the k nearest clips to a stored clip or to an uploaded file."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from app.api.deps import DescriptorDep, KQuery, LabelQuery, LibraryDep, UploadDep
from app.api.errors import error_responses
from app.api.schemas import (
    ClipOut,
    ClipSearchResponse,
    SearchHit,
    UploadedClipOut,
    UploadSearchResponse,
)
from app.services import clips as clip_service
from app.services import search as search_service

router = APIRouter(prefix="/search", tags=["search"])


@router.get(
    "",
    summary="Clips similar to a stored clip",
    responses=error_responses(404, 409, 422, 503),
)
def search_by_clip(
    library: LibraryDep,
    descriptor: DescriptorDep,
    clip: Annotated[int, Query(description="Id of the query clip.", examples=[7])],
    k: KQuery = 10,
    label: LabelQuery = None,
) -> ClipSearchResponse:
    """The `k` clips nearest to clip `clip` under `descriptor`, nearest first, never the
    query clip itself; Euclidean distances. Fewer than `k` only when the library (or the
    `label`) has fewer other clips."""
    query = clip_service.get_clip(library, clip)
    hits = search_service.search_by_clip(library, query, descriptor, k, label=label)
    return ClipSearchResponse(
        query=ClipOut.of(query),
        descriptor=descriptor,
        k=k,
        results=[SearchHit.of(h) for h in hits],
    )


@router.post(
    "",
    summary="Clips similar to an uploaded file",
    responses=error_responses(413, 415, 422, 503),
)
def search_by_upload(
    library: LibraryDep,
    upload: UploadDep,
    descriptor: DescriptorDep,
    k: KQuery = 10,
    label: LabelQuery = None,
) -> UploadSearchResponse:
    """Describe the uploaded clip (same fields as `POST /clips`) without storing it and
    return the `k` nearest stored clips; nothing is excluded (an identical stored clip comes
    first, at distance 0)."""
    query, hits = search_service.search_by_upload(library, upload, descriptor, k, label=label)
    return UploadSearchResponse(
        query=UploadedClipOut.of(query),
        descriptor=descriptor,
        k=k,
        results=[SearchHit.of(h) for h in hits],
    )
