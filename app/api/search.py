"""/search: the k nearest clips to a stored clip or to an uploaded file."""

from __future__ import annotations

import os
import re
from typing import Annotated

import anyio
from fastapi import APIRouter, Query, Request, Response
from starlette.types import ASGIApp, Receive, Scope, Send

from app.api import render
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
from app.api.search_lane import SearchLane
from app.errors import InvalidInput, MocapError
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


class PlainSearches:
    """The innermost ASGI layer (``create_app`` adds it first): a plain ``GET /search``
    (:func:`plain_search_query`: what nearly every search sends) is answered here by the
    route's own search (:func:`plain_search_body`), skipping FastAPI's routing, query reading
    and exception layers, which cost as much CPU as the rest of the request at a million
    clips (bench/README.md). The layers outside it — the request guard (host, API key,
    per-client limits), CORS, compression, size limits — run as for any request. Every
    other request, and a plain one whose search raises (a missing clip, a bad ``k`` or
    descriptor: the answer is an error), goes to FastAPI unchanged, so every error, the
    OpenAPI document and the route itself stay FastAPI's. ``enabled`` is False when reads
    need a key (``MOCAP_REQUIRE_KEY_FOR_READS``: the key check is a route dependency)."""

    def __init__(self, app: ASGIApp, *, enabled: bool = True) -> None:
        self.app = app
        self.enabled = enabled

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (
            not self.enabled
            or scope["type"] != "http"
            or scope["path"] != "/search"
            or scope["method"] != "GET"
        ):
            await self.app(scope, receive, send)
            return
        values = plain_search_query(scope["query_string"])
        library = getattr(scope["app"].state, "library", None)
        if values is None or library is None:
            await self.app(scope, receive, send)
            return
        try:
            body = await plain_search_body(library, **values)  # type: ignore[arg-type]
        except MocapError:  # FastAPI answers it (its error, its bytes)
            await self.app(scope, receive, send)
            return
        # The headers Response(body, media_type="application/json") sends, in its order.
        headers = [(b"content-length", str(len(body)).encode()), JSON_TYPE]
        await send({"type": "http.response.start", "status": 200, "headers": headers})
        await send({"type": "http.response.body", "body": body})


JSON_TYPE = (b"content-type", b"application/json")


async def plain_search_body(
    library: Library, clip: int, k: int = 10, descriptor: str | None = None
) -> bytes:
    """The body of ``GET /search`` for a query without filters or collapse (a search's
    errors raised as :class:`MocapError`)."""
    if descriptor is None:
        descriptor = library.default_descriptor
    name = descriptor
    kind = (name, False, False, k > QUICK_K)  # the route's kind of search (see search_by_clip)
    LANE.in_flight += 1
    try:
        if SEARCHES.quick(kind) and library.settings.workers < CORES and LANE.wanted():
            # Other searches are in flight and a core is to spare beside the server's
            # processes: this one's scan runs in the lane, beside the loop's work on them
            # (app/api/search_lane.py); the rest runs here. With a process per core the
            # lane measured no faster and doubled the p99 (bench/README.md).
            query, vector = search_service.query_clip(library, clip, name, k)
            found = await LANE.nearest(library.indexes[name], vector, k, clip)
            answer = search_service.plain_answer(library, query, vector, name, k, found)
            return render.plain_clip_search(answer, name, k)
        return await SEARCHES.run(kind, lambda: _plain_search(library, clip, name, k))
    finally:
        LANE.in_flight -= 1


def _plain_search(library: Library, clip: int, descriptor: str, k: int) -> bytes:
    answer = search_service.find_plain(library, clip, descriptor, k)
    return render.plain_clip_search(answer, descriptor, k)


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


router.add_api_route(
    "",
    search_by_clip,
    methods=["GET"],
    summary="Clips similar to a stored clip",
    response_model=ClipSearchResponse,
    responses=error_responses(404, 409, 422, 503),
)


# Slow searches running at once: more threads than cores only fight over the GIL.
SEARCHES = Offload(anyio.CapacityLimiter(4))
LANE = SearchLane()  # quick plain searches' scans while others are in flight
CORES = len(os.sched_getaffinity(0))  # the cores this process may run on
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
