"""The browser UI: the page at ``/``, its static files, and the endpoints only it needs.

``mount_ui(app)`` is the one call ``create_app`` makes: it serves ``app/static`` at
``/static``, the page at ``/`` and adds these routes:

* ``GET /clips/{id}/skeleton`` — canonical joint positions per frame and the bone list, for
  drawing stick figures (``POST /skeleton`` does the same for an uploaded, unstored file);
* ``POST /inspect`` — the animations of an uploaded file (to choose one before storing it);
* ``GET /map`` — every clip placed in 2-D (FMDistance's 3-MAN features and a PCA of a
  descriptor), with an outlier flag;
* ``GET /library/clips`` — the clip list filtered by name and label; ``GET /library/labels``
  and ``GET /library/licences`` the labels and licences in use.

The computations live in :mod:`app.services.previews` (stick figures) and
:mod:`app.services.library_map` (the map, the filtered list).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, FastAPI, Query, Request, Response
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field

from app.api.auth import read_dependencies
from app.api.clips import check_page
from app.api.compression import MINIMUM_BYTES
from app.api.deps import ClipDep, DescriptorDep, LabelQuery, LibraryDep, SettingsDep, UploadDep
from app.api.errors import error_responses
from app.api.query_check import CheckedQueryRoute
from app.api.routers import add_router
from app.api.schemas import ClipOut, ClipPage
from app.services import library_map as ui_service
from app.services import previews
from app.services.describe import read_motion
from app.text import checked_text

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"
INDEX_HTML = STATIC_DIR / "index.html"

# The page loads only its own files: no inline script, no other origin.
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'"
)

router = APIRouter(tags=["ui"], route_class=CheckedQueryRoute)


class SkeletonExtent(BaseModel):
    height: float = Field(
        description="The tallest frame of the span: its highest joint minus its lowest."
    )
    reach: float = Field(
        description="The farthest any joint gets from the pelvis over the floor in the span."
    )


class SkeletonOut(BaseModel):
    """Canonical joint positions per frame, for drawing a stick figure."""

    clip_id: int | None = Field(description="The clip (null for an uploaded file).")
    fps: float = Field(description="Frames per second of `frames`.")
    start: float = Field(
        description="Seconds of the file (lead-in frames included, as `start` asks) of the "
        "first frame returned."
    )
    frame_count: int = Field(description="Frames returned.")
    truncated: bool = Field(
        description="True when the span (default: the whole clip) is longer than the frames "
        "returned (cut at the end)."
    )
    duration: float = Field(description="Seconds covered by the frames returned.")
    source_frame_count: int = Field(description="Frames of the clip after lead-in frames.")
    source_duration: float = Field(description="Seconds covered by the whole clip.")
    source_fps: float = Field(description="The file's own frame rate.")
    lead_in_frames: int = Field(description="Rest-pose frames at the start left out.")
    units: str = Field(description='Always "body heights".')
    joints: list[str] = Field(description="Canonical joint names, the order of each frame.")
    bones: list[list[int]] = Field(description="[parent index, child index] pairs.")
    extent: SkeletonExtent = Field(
        description="Room the figure needs around its pelvis over the span (every frame of "
        "it, not only those returned): for framing it."
    )
    encoding: str = Field(description="`json` (`frames`) or `compact` (`root`, `offsets`).")
    frames: list[list[list[float]]] | None = Field(
        None,
        description="`json`: [frame][joint] = [x, y, z]: body heights, y up, x the subject's "
        "left and z its forward at the first frame, origin on the floor under the first "
        "frame's pelvis (4 decimals).",
    )
    root: str | None = Field(
        None,
        description="`compact`: base64 of little-endian float32 [frame][x, y, z], the pelvis.",
    )
    offsets: str | None = Field(
        None,
        description="`compact`: base64 of little-endian int16 [frame][joint][x, y, z], each "
        "joint minus the pelvis in `offset_unit` body heights.",
    )
    offset_unit: float | None = Field(None, description="`compact`: 0.0001 body heights.")


class InspectedAnimation(BaseModel):
    name: str = Field(description="As the file names it (`animation N` when it does not).")
    frame_count: int
    duration: float = Field(description="Seconds.")
    selected: bool = Field(
        description="The one read: named in `animation`, else the longest that moves a node "
        "(what `POST /clips` stores without `animation`)."
    )


class InspectOut(BaseModel):
    """What an uploaded file holds, before it is stored or searched with."""

    format: str
    filenames: list[str]
    frame_count: int = Field(description="Frames of the animation read.")
    duration: float = Field(description="Seconds of the animation read.")
    animations: list[InspectedAnimation] = Field(
        description="FBX/glTF: every animation of the file (each can be its own clip); empty "
        "for BVH and ASF/AMC, which hold one motion."
    )


class MapClip(BaseModel):
    id: int
    name: str
    labels: list[str]
    format: str
    duration: float
    frame_count: int
    x: float | None = Field(description="3-MAN e_all (null without a kinetic vector).")
    y: float | None = Field(description="3-MAN r_u/l.")
    three_man: list[float] | None = Field(description="[e_all, r_u/l, r_l/t].")
    pca: list[float] | None = Field(
        description="First two principal components of the descriptor's vector."
    )
    outlier: bool = Field(description="Isolated in the library under the descriptor.")
    outlier_score: float | None = Field(
        description="Modified z-score of the clip's isolation (outlier above 3.5)."
    )


class MapOut(BaseModel):
    descriptor: str
    count: int
    three_man_available: bool = Field(
        description="False when the service has no kinetic descriptor to derive 3-MAN from."
    )
    three_man_axes: list[str]
    pca_explained_variance: list[float] = Field(
        description="Fraction of the variance along each PCA axis."
    )
    outlier_rule: str
    clips: list[MapClip]


class LabelCount(BaseModel):
    label: str
    count: int


class LicenceCount(BaseModel):
    licence: str = Field(description="As stored (one spelling per licence, any case).")
    count: int


def _library_map(request: Request) -> ui_service.LibraryMap:
    maps = getattr(request.app.state, "library_map", None)
    if maps is None:
        maps = request.app.state.library_map = ui_service.LibraryMap()
    return maps


def _skeleton_cache(request: Request) -> previews.SkeletonCache:
    cache: previews.SkeletonCache = request.app.state.skeleton_cache
    return cache


FpsQuery = Annotated[
    float,
    Query(
        description=f"Frames per second, {previews.MIN_FPS:g} to {previews.MAX_FPS:g} (need not "
        "be whole: 0.2 gives an overview of a long take).",
        examples=[30],
    ),
]
MaxFramesQuery = Annotated[
    int,
    Query(
        description="Most frames to return, 1 to "
        f"{previews.MAX_SKELETON_FRAMES}; a longer span is cut (`truncated`)."
    ),
]
EncodingQuery = Annotated[
    str,
    Query(
        description="`json`: `frames` as nested lists; `compact`: `root` (float32) and "
        "`offsets` (int16) in base64, a third of the size (see `root`, `offsets`)."
    ),
]
SpanStart = Annotated[
    float | None,
    Query(description="From here, seconds of the file (lead-in frames included)."),
]
SpanEnd = Annotated[float | None, Query(description="Up to here, seconds of the file.")]


@router.get(
    "/clips/{clip_id}/skeleton",
    summary="Stick-figure joint positions of a clip",
    response_class=Response,
    responses={
        200: {"model": SkeletonOut, "description": "Joint positions per frame."},
        304: {"description": "Unchanged since the ETag sent in If-None-Match."},
        **error_responses(404, 422, 503),
    },
)
def clip_skeleton(
    clip: ClipDep,
    library: LibraryDep,
    request: Request,
    fps: FpsQuery = previews.DEFAULT_FPS,
    max_frames: MaxFramesQuery = previews.MAX_SKELETON_FRAMES,
    start: SpanStart = None,
    end: SpanEnd = None,
    encoding: EncodingQuery = "json",
) -> Response:
    """The clip's canonical joints (`joints`), per frame resampled to `fps`, in body heights
    with y up, and the bones between them: what the UI draws. Rest-pose lead-in frames are
    left out as for the descriptors; at most `max_frames` frames (default and cap 600) from
    `start` to `end` (default: the whole clip), so any part of a take of any length can be
    fetched (a low `fps` for an overview, windows of it in detail)."""
    skeleton = previews.clip_skeleton(
        library,
        _skeleton_cache(request),
        clip,
        fps,
        max_frames,
        start=start,
        end=end,
        encoding=encoding,
    )
    headers = {"ETag": skeleton.etag, "Cache-Control": "private, max-age=3600"}
    if request.headers.get("if-none-match") == skeleton.etag:
        return Response(status_code=304, headers=headers)
    if "gzip" in request.headers.get("accept-encoding", "") and len(skeleton.body) > MINIMUM_BYTES:
        # Compressed once and kept (the compression middleware leaves an encoded body alone).
        headers.update({"Content-Encoding": "gzip", "Vary": "Accept-Encoding"})
        return Response(content=skeleton.gzipped, media_type="application/json", headers=headers)
    return Response(content=skeleton.body, media_type="application/json", headers=headers)


@router.post(
    "/skeleton",
    summary="Stick-figure joint positions of an uploaded file",
    response_class=Response,
    responses={
        200: {"model": SkeletonOut, "description": "Joint positions per frame."},
        # 400: a multipart body that cannot be parsed
        **error_responses(400, 413, 415, 422),
    },
)
def upload_skeleton(
    upload: UploadDep,
    settings: SettingsDep,
    library: LibraryDep,
    fps: FpsQuery = previews.DEFAULT_FPS,
    max_frames: MaxFramesQuery = previews.MAX_SKELETON_FRAMES,
    encoding: EncodingQuery = "json",
) -> Response:
    """As `GET /clips/{id}/skeleton` for a file sent like `POST /clips` (nothing stored):
    the UI previews a file dropped as a search query with it."""
    # The same memory bound as describing an upload (MOCAP_MAX_FRAME_VALUES).
    limits = dataclasses.replace(settings.parse_limits, max_values=settings.max_frame_values)
    body = previews.upload_skeleton(
        upload, limits, fps, max_frames, library.parsers, encoding=encoding
    )
    return Response(content=body, media_type="application/json")


@router.post(
    "/inspect",
    summary="The animations an uploaded file holds",
    responses=error_responses(400, 413, 415, 422),
)
def inspect_upload(upload: UploadDep, settings: SettingsDep, library: LibraryDep) -> InspectOut:
    """Read a file sent like `POST /clips` (nothing stored) and list its animations with their
    lengths, so one can be chosen (the `animation` field of `POST /clips`, `POST /search`, `POST
    /skeleton`) before a multi-animation FBX or glTF file is stored or searched with. FBX and
    glTF are read in a parser worker, as for every upload. An `animation` the file does not have
    is 422 `unknown_animation`, listing those it has."""
    limits = dataclasses.replace(settings.parse_limits, max_values=settings.max_frame_values)
    read = read_motion(upload, limits, library.parsers)
    return InspectOut(
        format=upload.format,
        filenames=[part.filename for part in upload.parts],
        frame_count=read.motion.frame_count,
        duration=round(read.motion.duration, 6),
        animations=[
            InspectedAnimation(
                name=a.name,
                frame_count=a.frame_count,
                duration=round(a.duration, 6),
                selected=a.name == read.animation,
            )
            for a in read.animations
        ],
    )


@router.get(
    "/map",
    summary="The whole library in 2-D",
    response_class=Response,
    responses={200: {"model": MapOut, "description": "The map."}, **error_responses(422)},
)
def library_map(library: LibraryDep, descriptor: DescriptorDep, request: Request) -> Response:
    """Every clip with 2-D coordinates: `x`, `y` = FMDistance's 3-MAN features e_all and
    r_u/l (all three in `three_man`), computed from the stored kinetic vectors, and `pca` =
    the first two principal components of `descriptor`'s vectors; `outlier` marks clips whose
    `descriptor` vectors are far from their nearest neighbours compared with the other
    clips' (robust z-score of the mean distance to the 5 nearest, over 3.5).

    Computed once per change of the library; for a large library in the background, the
    last map meanwhile (clips stored since then have no `pca` or outlier flag yet)."""
    body = _library_map(request).body(library, descriptor)
    return Response(content=body, media_type="application/json")


@router.get(
    "/library/clips", summary="Find clips by name and label", responses=error_responses(422)
)
def find_clips(
    library: LibraryDep,
    settings: SettingsDep,
    q: Annotated[
        str | None, Query(description="Only clips whose name contains this (any case).")
    ] = None,
    label: LabelQuery = None,
    limit: Annotated[int, Query(description="Page size, 1 to MOCAP_MAX_PAGE_SIZE.")] = 50,
    offset: Annotated[int, Query(description="Clips to skip (≥ 0).")] = 0,
) -> ClipPage:
    """As `GET /clips`, with a name filter: clips in id order, a page at a time."""
    check_page(settings, limit, offset)
    items, total = ui_service.find_clips(
        library,
        q=checked_text("q", q or "").strip() or None,
        label=label,
        limit=limit,
        offset=offset,
    )
    return ClipPage(total=total, limit=limit, offset=offset, items=[ClipOut.of(c) for c in items])


@router.get("/library/labels", summary="Labels in use")
def list_labels(library: LibraryDep) -> list[LabelCount]:
    """Every label carried by some clip, with its number of clips, most used first (labels
    differing only in case count as one)."""
    return [LabelCount(label=label, count=n) for label, n in ui_service.label_counts(library)]


@router.get("/library/licences", summary="Licences in use")
def list_licences(library: LibraryDep) -> list[LicenceCount]:
    """Every licence some clip has, with its number of clips, most used first (licences
    differing only in case or surrounding spaces count as one, as the `licence=` filters
    compare them): what the UI's licence filter offers."""
    return [
        LicenceCount(licence=licence, count=n) for licence, n in ui_service.licence_counts(library)
    ]


def index_page() -> FileResponse:
    return FileResponse(
        INDEX_HTML,
        media_type="text/html",
        headers={"Content-Security-Policy": CONTENT_SECURITY_POLICY, "Cache-Control": "no-cache"},
    )


def mount_ui(app: FastAPI) -> None:
    """Serve the UI from ``app``: ``/`` (the page), ``/static/*`` and the routes above.

    The page's route is put first, so it wins over any other ``GET /``. The data routes are
    reading routes: with ``MOCAP_REQUIRE_KEY_FOR_READS`` they need the API key (the page asks
    for it); the page and ``/static`` stay open. Needs ``app.state.settings`` (set by
    ``create_app``). Calling it twice does nothing the second time.
    """
    state: Any = app.state
    if getattr(state, "ui_mounted", False):
        return
    state.ui_mounted = True
    state.skeleton_cache = previews.SkeletonCache(previews.preview_store(state.settings).root)
    state.library_map = ui_service.LibraryMap()
    app.add_api_route("/", index_page, methods=["GET"], include_in_schema=False)
    app.router.routes.insert(0, app.router.routes.pop())
    # The page and its files are open (like /docs); the data routes are reading routes.
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    reads = read_dependencies(state.settings)
    add_router(
        app, router, dependencies=reads, responses=error_responses(401, 403) if reads else None
    )
