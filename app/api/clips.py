"""/clips: upload, list, read, download, change and delete clips."""

from __future__ import annotations

from typing import Annotated, Literal
from urllib.parse import quote

from fastapi import APIRouter, Query, Response, status

from app.api.auth import WriteAccess
from app.api.deps import ClipDep, LibraryDep, SettingsDep, UploadDep
from app.api.errors import error_responses
from app.api.schemas import ClipOut, ClipPage, ClipUpdate
from app.errors import InvalidInput
from app.services import clips as clip_service
from app.services.ingest import ingest
from app.services.uploads import normalise_labels, normalise_name

router = APIRouter(prefix="/clips", tags=["clips"])


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    summary="Upload a clip",
    dependencies=[WriteAccess],
    responses={
        200: {"model": ClipOut, "description": "The same content was already stored: that clip."},
        **error_responses(400, 401, 403, 413, 415, 422, 503),
    },
)
def create_clip(upload: UploadDep, library: LibraryDep, response: Response) -> ClipOut:
    """Store a clip: one BVH file as `file`, or an ASF skeleton as `skeleton` with an AMC
    motion as `motion`. The clip is parsed and described under every descriptor before
    anything is stored; uploading identical bytes again returns the stored clip (200)."""
    result = ingest(library, upload)
    if result.created:
        response.headers["Location"] = f"/clips/{result.clip.id}"
    else:
        response.status_code = status.HTTP_200_OK
    return ClipOut.of(result.clip)


@router.get("", summary="List clips", responses=error_responses(422, 503))
def list_clips(
    library: LibraryDep,
    settings: SettingsDep,
    limit: Annotated[int, Query(description="Page size, 1 to MOCAP_MAX_PAGE_SIZE.")] = 50,
    offset: Annotated[int, Query(description="Clips to skip.")] = 0,
    label: Annotated[str | None, Query(description="Only clips carrying this label.")] = None,
) -> ClipPage:
    """Clips in id order, a page at a time, with the total count."""
    if not 1 <= limit <= settings.max_page_size:
        raise InvalidInput(f"limit: must be between 1 and {settings.max_page_size}, got {limit}")
    if not 0 <= offset <= clip_service.MAX_ID:
        raise InvalidInput(f"offset: must be between 0 and {clip_service.MAX_ID}, got {offset}")
    items, total = clip_service.list_clips(library, label=label, limit=limit, offset=offset)
    return ClipPage(total=total, limit=limit, offset=offset, items=[ClipOut.of(c) for c in items])


@router.get("/{clip_id}", summary="Get a clip", responses=error_responses(404, 422, 503))
def get_clip(
    clip: ClipDep,
    library: LibraryDep,
    include: Annotated[
        list[str],
        Query(description="`descriptors` adds every stored descriptor vector by name."),
    ] = [],  # noqa: B006 - FastAPI copies defaults per request
) -> ClipOut:
    """One clip; with `?include=descriptors` also its descriptor vectors."""
    wanted = {word.strip() for value in include for word in value.split(",") if word.strip()}
    unknown = wanted - {"descriptors"}
    if unknown:
        raise InvalidInput(f"include: unknown {', '.join(sorted(unknown))}; use 'descriptors'")
    vectors = clip_service.clip_vectors(library, clip.id) if wanted else None
    return ClipOut.of(clip, vectors)


@router.get(
    "/{clip_id}/file",
    summary="Download the original upload",
    response_class=Response,
    responses={
        200: {
            "description": "The BVH file, or for ASF/AMC a ZIP of both (or one `part`).",
            "content": {"application/octet-stream": {}, "application/zip": {}},
        },
        **error_responses(404, 422, 503),
    },
)
def download_clip(
    clip: ClipDep,
    library: LibraryDep,
    part: Annotated[
        Literal["file", "skeleton", "motion"] | None,
        Query(description="One uploaded part, byte for byte (ASF/AMC: skeleton or motion)."),
    ] = None,
    start: Annotated[
        float | None, Query(description="Cut from here: seconds from the first frame.")
    ] = None,
    end: Annotated[float | None, Query(description="Cut up to here (exclusive), seconds.")] = None,
) -> Response:
    """The uploaded bytes, unchanged; with `start` and/or `end` the motion cut to that span
    (BVH: same hierarchy, only those frames; ASF/AMC: the ASF and the cut AMC, frames
    renumbered from 1)."""
    download = clip_service.clip_download(library, clip, part, start, end)
    return Response(
        content=download.data,
        media_type=download.media_type,
        headers={"Content-Disposition": _attachment(download.filename)},
    )


@router.patch(
    "/{clip_id}",
    summary="Rename or relabel a clip",
    dependencies=[WriteAccess],
    responses=error_responses(400, 401, 403, 404, 422, 503),
)
def update_clip(clip: ClipDep, changes: ClipUpdate, library: LibraryDep) -> ClipOut:
    """Change the name and/or replace the labels; fields left out keep their value."""
    name = normalise_name(changes.name) if changes.name is not None else None
    if changes.name is not None and name is None:
        raise InvalidInput("name: must not be blank")
    labels = normalise_labels(changes.labels) if changes.labels is not None else None
    return ClipOut.of(clip_service.update_clip(library, clip.id, name=name, labels=labels))


@router.delete(
    "/{clip_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a clip",
    dependencies=[WriteAccess],
    response_class=Response,
    responses=error_responses(401, 403, 404, 422, 503),
)
def delete_clip(clip: ClipDep, library: LibraryDep) -> Response:
    """Remove the clip, its vectors from every index and its stored files."""
    clip_service.delete_clip(library, clip.id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


# Characters kept in the plain-ASCII ``filename=`` fallback; anything else (quotes,
# backslashes, control characters, non-ASCII) becomes "_". ``filename*`` (RFC 5987/6266)
# carries the exact name, percent-encoded.
_PLAIN_FILENAME = frozenset(
    "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789 !#$&'()+,-.=@[]^_`{}~"
)
_ATTR_CHARS = "!#$&+-.^_`|~"  # RFC 5987 attr-chars besides letters and digits


def _attachment(filename: str) -> str:
    """A ``Content-Disposition`` that names ``filename`` safely, whatever it contains."""
    plain = "".join(c if c in _PLAIN_FILENAME else "_" for c in filename).strip() or "download"
    exact = quote(filename, safe=_ATTR_CHARS, encoding="utf-8", errors="replace")
    return f"attachment; filename=\"{plain}\"; filename*=UTF-8''{exact}"
