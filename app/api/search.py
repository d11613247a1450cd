"""/search: the k nearest clips to a stored clip or to an uploaded file."""

from __future__ import annotations

from typing import Annotated

import anyio
from fastapi import APIRouter, Query, Request, Response

from app.api import render
from app.api.deps import (
    DescriptorDep,
    DescriptorQuery,
    KQuery,
    LabelQuery,
    LibraryDep,
    UploadDep,
)
from app.api.errors import error_responses
from app.api.offload import Offload
from app.api.schemas import (
    ClipSearchResponse,
    SearchHit,
    UploadedClipOut,
    UploadSearchResponse,
)
from app.errors import InvalidInput
from app.services import search as search_service
from app.services.library import Library

router = APIRouter(prefix="/search", tags=["search"])


@router.get(
    "",
    summary="Clips similar to a stored clip",
    response_model=ClipSearchResponse,
    responses=error_responses(404, 409, 422, 503),
)
async def search_by_clip(
    request: Request,
    clip: Annotated[int, Query(description="Id of the query clip.", examples=[7])],
    k: KQuery = 10,
    descriptor: DescriptorQuery = None,
    label: LabelQuery = None,
) -> Response:
    """The `k` clips nearest to clip `clip` under `descriptor`, nearest first, never the
    query clip itself; Euclidean distances. Fewer than `k` only when the library (or the
    `label`) has fewer other clips."""
    # The hot path (see bench/README.md): no dependency functions (each sync one is a
    # thread-pool hop), no SQL (the index and the in-memory catalogue), the body serialised
    # once by orjson (app/api/render.py). Run on the event loop while searches of its kind
    # have been quick, in a thread when they have been slow (app/api/offload.py).
    library: Library = request.app.state.library
    if descriptor is None:
        descriptor = library.default_descriptor
    body = await SEARCHES.run(
        (descriptor, bool(label), k > QUICK_K),
        lambda: _search_by_clip(library, clip, descriptor, k, label),
    )
    return Response(body, media_type="application/json")


# Slow searches running at once: more threads than cores only fight over the GIL.
SEARCHES = Offload(anyio.CapacityLimiter(4))
QUICK_K = 100  # more hits than this are searches of another kind (more to show)


def _search_by_clip(
    library: Library, clip: int, descriptor: str, k: int, label: list[str] | None
) -> bytes:
    query, hits = search_service.search_by_clip_id(library, clip, descriptor, k, label=label)
    return render.clip_search(query, descriptor, k, [(h.clip, h.distance) for h in hits])


@router.post(
    "",
    summary="Clips similar to an uploaded file",
    responses=error_responses(400, 413, 415, 422, 503),
)
def search_by_upload(
    library: LibraryDep,
    upload: UploadDep,
    descriptor: DescriptorDep,
    k: KQuery = 10,
    label: LabelQuery = None,
    clip: Annotated[
        str | None,
        Query(description="Not allowed here: search by a stored clip with `GET /search?clip=`."),
    ] = None,
) -> UploadSearchResponse:
    """Describe the uploaded clip (same fields as `POST /clips`) without storing it and
    return the `k` nearest stored clips; nothing is excluded (an identical stored clip comes
    first, at distance 0)."""
    if clip is not None:
        raise InvalidInput("clip: give a clip id or a file, not both")
    query, hits = search_service.search_by_upload(library, upload, descriptor, k, label=label)
    return UploadSearchResponse(
        query=UploadedClipOut.of(query),
        descriptor=descriptor,
        k=k,
        results=[SearchHit.of(h) for h in hits],
    )
