"""/search: the k nearest clips to a stored clip or to an uploaded file."""

from __future__ import annotations

import re
from collections.abc import Callable, Coroutine
from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Query, Request, Response

from app.api import render
from app.api.auth import read_dependencies
from app.api.deps import (
    ClipIdQuery,
    CollapseQuery,
    DescriptorDep,
    DescriptorQuery,
    KQuery,
    LabelQuery,
    LibraryDep,
    LicenceQuery,
    UploadDep,
)
from app.api.errors import error_responses
from app.api.offload import Offload
from app.api.query_check import CheckedQueryRoute
from app.api.schemas import (
    ClipSearchResponse,
    SearchHit,
    UploadedClipOut,
    UploadSearchResponse,
)
from app.errors import InvalidInput
from app.services import search as search_service
from app.services.library import Library

router = APIRouter(prefix="/search", tags=["search"], route_class=CheckedQueryRoute)

# A plain search's query: ``clip``, ``k`` and ``descriptor``, each once, with values FastAPI
# reads as they are written (digits without a leading zero — at most 18, so a clip id is
# within MAX_ID — and a bare name).
PLAIN_PARAMETER = re.compile(rb"(clip|k)=([1-9][0-9]{0,17})|(descriptor)=([A-Za-z0-9_]{1,64})")


def plain_search_query(query: bytes) -> dict[str, int | str] | None:
    """The arguments of ``GET /search`` for a plain query (see :data:`PLAIN_PARAMETER`) with a
    ``clip``; ``None`` for any other (label or licence filters, collapse, encoded or repeated
    values, a missing clip...), which FastAPI reads."""
    values: dict[str, int | str] = {}
    for part in query.split(b"&"):
        match = PLAIN_PARAMETER.fullmatch(part)
        if match is None:
            return None
        name = (match[1] or match[3]).decode()
        value: int | str = int(match[2]) if match[1] is not None else match[4].decode()
        if name in values:
            return None
        values[name] = value
    return values if "clip" in values else None


class PlainSearchRoute(CheckedQueryRoute):
    """``GET /search`` reads a plain query (:func:`plain_search_query`: what nearly every
    search sends) itself and calls the route's function: FastAPI's reading of the query
    parameters cost a fifth of a search's CPU at a million clips (bench/README.md). Any other
    query goes FastAPI's way, so every answer and every error is the one FastAPI gives; so
    does every request when the route has dependencies — its own, or the reading routers'
    key check (``MOCAP_REQUIRE_KEY_FOR_READS``, :func:`app.api.auth.read_dependencies`,
    which ``create_app`` gives this router)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        if self.dependant.dependencies:
            return handler
        endpoint = self.endpoint

        async def plain(request: Request) -> Response:
            values = plain_search_query(request.scope.get("query_string", b""))
            if values is None or read_dependencies(request.app.state.settings):
                return await handler(request)
            response: Response = await endpoint(request, **values)
            return response

        return plain


async def search_by_clip(
    request: Request,
    clip: ClipIdQuery,
    k: KQuery = 10,
    descriptor: DescriptorQuery = None,
    label: LabelQuery = None,
    licence: LicenceQuery = None,
    collapse: CollapseQuery = None,
) -> Response:
    """The `k` clips nearest to clip `clip` under `descriptor`, nearest first, never the
    query clip itself; Euclidean distances and each result's `similarity`. Fewer than `k`
    only when the library (or the `label` and `licence` filters) has fewer other clips. A
    filtered search returns the unfiltered ranking restricted to the clips the filters keep.
    With `collapse=capture` the clips near-identical to the query are set aside in
    `query_others`."""
    # The hot path (see bench/README.md): no dependency functions (each sync one is a
    # thread-pool hop), no SQL (the index and the in-memory catalogue), the body serialised
    # once by orjson (app/api/render.py). Run on the event loop while searches of its kind
    # have been quick, in a thread when they have been slow (app/api/offload.py).
    library: Library = request.app.state.library
    if descriptor is None:
        descriptor = library.default_descriptor
    capture = collapse == "capture"
    # Licence filters narrow the ids like labels: one kind with them.
    body = await SEARCHES.run(
        (descriptor, bool(label) or bool(licence), capture, k > QUICK_K),
        lambda: _search_by_clip(library, clip, descriptor, k, label, licence, capture),
    )
    return Response(body, media_type="application/json")


router.add_api_route(  # router.get() with this route's own class
    "",
    search_by_clip,
    methods=["GET"],
    summary="Clips similar to a stored clip",
    response_model=ClipSearchResponse,
    responses=error_responses(404, 409, 422, 503),
    route_class_override=PlainSearchRoute,
)


# Slow searches running at once: more threads than cores only fight over the GIL.
SEARCHES = Offload(anyio.CapacityLimiter(4))
QUICK_K = 100  # more hits than this are searches of another kind (more to show)


def _search_by_clip(
    library: Library,
    clip: int,
    descriptor: str,
    k: int,
    label: list[str] | None,
    licence: list[str] | None,
    collapse: bool,
) -> bytes:
    answer = search_service.find_by_clip(
        library, clip, descriptor, k, label=label, licence=licence, collapse=collapse
    )
    return render.clip_search(
        answer.clip,
        descriptor,
        k,
        answer.hits,
        query_others=answer.query_others if collapse else None,
    )


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
    licence: LicenceQuery = None,
    collapse: CollapseQuery = None,
    clip: Annotated[
        str | None,
        Query(description="Not allowed here: search by a stored clip with `GET /search?clip=`."),
    ] = None,
) -> UploadSearchResponse:
    """Describe the uploaded clip (same fields as `POST /clips`) without storing it and
    return the `k` nearest stored clips; nothing is excluded: when the file is already
    stored, `query.stored_clip` names that clip, which comes first at distance 0."""
    if clip is not None:
        raise InvalidInput("clip: give a clip id or a file, not both")
    capture = collapse == "capture"
    query, hits = search_service.search_by_upload(
        library, upload, descriptor, k, label=label, licence=licence, collapse=capture
    )
    stored = search_service.stored_copy(library, query.content_hash)
    return UploadSearchResponse(
        query=UploadedClipOut.of(query, stored),
        descriptor=descriptor,
        k=k,
        results=[SearchHit.of(h, collapsed=capture) for h in hits],
    )
