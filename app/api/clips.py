"""/clips: upload, list, read, download, change and delete clips."""

from __future__ import annotations

from typing import Annotated, Literal
from urllib.parse import quote

from fastapi import APIRouter, Query, Response, status
from pydantic import BaseModel, Field

from app.api.auth import WriteAccess
from app.api.deps import (
    LABEL_FILTER_DOC,
    ClipDep,
    LabelQuery,
    LibraryDep,
    LicenceQuery,
    SettingsDep,
    UploadDep,
)
from app.api.errors import error_responses
from app.api.query_check import CheckedQueryRoute
from app.api.schemas import ClipOut, ClipPage, ClipUpdate, LabelChanges, LabelsChanged
from app.config import Settings
from app.db.clip_filters import ClipFilter
from app.db.clips import SORT_KEYS
from app.errors import InvalidInput
from app.labels import label_filter, normalise_labels
from app.services import clips as clip_service
from app.services.describe import span_frames
from app.services.ingest import ingest
from app.services.uploads import SCENE_FORMATS, normalise_name, normalise_note

router = APIRouter(prefix="/clips", tags=["clips"], route_class=CheckedQueryRoute)


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    summary="Upload a clip",
    dependencies=[WriteAccess],
    responses={
        200: {
            "model": ClipOut,
            "description": "The same content was already stored: that clip, as stored now "
            '(what the upload brought applied), with `"duplicate": true`.',
        },
        **error_responses(400, 401, 403, 413, 415, 422, 503),
    },
)
def create_clip(upload: UploadDep, library: LibraryDep, response: Response) -> ClipOut:
    """Store a clip: one BVH, FBX, glTF (.glb/.gltf), VRM animation (.vrma) or VRM (.vrm)
    file as `file`, or an ASF skeleton as `skeleton` with an AMC motion as `motion`, with
    optional `name`, `labels`, `source` and `licence`. FBX/glTF: the longest animation of the
    file that moves a node, or the one named in `animation`. The clip is parsed and described
    under every descriptor before anything is stored.

    Uploading identical content again stores nothing new: the answer is 200 with the stored
    clip and `"duplicate": true`, after applying what the upload brings — its labels are
    added to the clip's (case-insensitively), a given `name`, `source` or `licence` replaces
    the stored one."""
    result = ingest(library, upload)
    if result.created:
        response.headers["Location"] = f"/clips/{result.clip.id}"
        return ClipOut.of(result.clip)
    response.status_code = status.HTTP_200_OK
    return ClipOut.of(result.clip, duplicate=True)


TextQuery = Annotated[
    str | None,
    Query(
        description="Text to find, any case: every word (split on spaces) must appear in the "
        "clip's name, one of its file names, one of its labels, its source or its licence.",
        examples=["walk cmu"],
    ),
]
SORT_DOC = (
    "Order: `id` (default: the order clips were stored in), `name` (any case), `created_at` "
    "(date added), `duration`, `frame_count`; a leading `-` for descending "
    "(`sort=-created_at`: newest first). Ties go by id."
)


def sort_param(sort: str) -> str:
    if sort.removeprefix("-") not in SORT_KEYS:
        raise InvalidInput(
            f"sort: unknown {sort!r}; use one of {', '.join(SORT_KEYS)}, with a leading - "
            "for descending"
        )
    return sort


@router.get("", summary="List clips", responses=error_responses(422, 503))
def list_clips(
    library: LibraryDep,
    settings: SettingsDep,
    limit: Annotated[int, Query(description="Page size, 1 to MOCAP_MAX_PAGE_SIZE.")] = 50,
    offset: Annotated[int, Query(description="Clips to skip (≥ 0).")] = 0,
    label: LabelQuery = None,
    licence: LicenceQuery = None,
    q: TextQuery = None,
    sort: Annotated[str, Query(description=SORT_DOC, examples=["-created_at"])] = "id",
) -> ClipPage:
    """Clips a page at a time, with the total count: those carrying every `label`, of the
    `licence`s asked for and holding every word of `q`, ordered by `sort`."""
    check_page(settings, limit, offset)
    items, total = clip_service.list_clips(
        library,
        selection=ClipFilter.of(label=label, licence=licence, q=q),
        sort=sort_param(sort),
        limit=limit,
        offset=offset,
    )
    return ClipPage(total=total, limit=limit, offset=offset, items=[ClipOut.of(c) for c in items])


@router.post(
    "/labels",
    summary="Add or remove labels on many clips",
    dependencies=[WriteAccess],
    responses=error_responses(400, 401, 403, 422, 503),
)
def change_labels(changes: LabelChanges, library: LibraryDep) -> LabelsChanged:
    """Add `add` to and remove `remove` from every clip the selection keeps — `ids`, and/or
    `label`, `licence` and `q` as in `GET /clips` (all given must hold), or `all: true` —
    in one transaction. An added label goes at the end of a clip's labels unless the clip
    carries it already (in any case). `PATCH /clips/{id}` still *replaces* one clip's
    labels."""
    add = normalise_labels(changes.add)
    remove = normalise_labels(changes.remove)
    result = clip_service.relabel_clips(
        library, changes.selection(), add=add, remove=remove, every=changes.all
    )
    return LabelsChanged(
        matched=result.matched, changed=result.changed, added=list(add), removed=list(remove)
    )


@router.get("/{clip_id}", summary="Get a clip", responses=error_responses(404, 422, 503))
def get_clip(
    clip: ClipDep,
    library: LibraryDep,
    include: Annotated[
        list[str],
        Query(
            description="`descriptors` adds every stored descriptor vector by name, `mapping` "
            "which source joint became each canonical joint and how it was found; "
            "comma-separated or repeated (`include=descriptors,mapping`)."
        ),
    ] = [],  # noqa: B006 - FastAPI copies defaults per request
) -> ClipOut:
    """One clip; with `?include=descriptors` also its descriptor vectors, with
    `?include=mapping` its joint mapping."""
    wanted = {word.strip() for value in include for word in value.split(",") if word.strip()}
    unknown = wanted - {"descriptors", "mapping"}
    if unknown:
        raise InvalidInput(
            f"include: unknown {', '.join(sorted(unknown))}; use 'descriptors' or 'mapping'"
        )
    vectors = clip_service.clip_vectors(library, clip.id) if "descriptors" in wanted else None
    return ClipOut.of(clip, vectors, mapping="mapping" in wanted)


@router.get(
    "/{clip_id}/file",
    summary="Download the clip: the original upload, or BVH / FBX / GLB",
    response_class=Response,
    responses={
        200: {
            "description": (
                "The uploaded file, or for ASF/AMC a ZIP of both (or one `part`); with "
                "`format`, the clip converted (and with `rig`, retargeted)."
            ),
            "content": {
                "application/octet-stream": {},
                "application/zip": {},
                "model/gltf-binary": {},
            },
        },
        **error_responses(404, 422, 501, 503),
    },
)
def download_clip(
    clip: ClipDep,
    library: LibraryDep,
    part: Annotated[
        Literal["file", "skeleton", "motion"] | None,
        Query(description="One uploaded part, byte for byte (ASF/AMC: skeleton or motion)."),
    ] = None,
    file_format: Annotated[
        Literal["bvh", "fbx", "glb"] | None,
        Query(
            alias="format",
            description=(
                "`bvh`: a BVH file (ZXY rotation channels on every joint, root translation); "
                "`fbx`: binary FBX 7.4 written by Blender's exporter (limb nodes, one "
                "animation stack; 501 `fbx_unavailable` where Blender is not installed); "
                "`glb`: binary glTF 2.0 (a node per joint, a skin, one animation; metres, "
                "+Y up). Of the clip's own skeleton, or of `rig`'s."
            ),
        ),
    ] = None,
    units: Annotated[
        Literal["cm", "m", "in"] | None,
        Query(
            description="BVH and FBX lengths: centimetres, metres or inches. Default: the "
            "skeleton's own unit for BVH and ASF/AMC skeletons, centimetres for FBX and glTF "
            "ones. GLB is always metres."
        ),
    ] = None,
    fps: Annotated[
        float | None,
        Query(
            description="Frame rate of the file (1 to 1000): rotations slerped, translations "
            "interpolated, the first and last frames kept. Default: the clip's own."
        ),
    ] = None,
    root: Annotated[
        Literal["keep", "in-place", "extract"] | None,
        Query(
            description="`keep` (default): the root as captured; `in-place`: the pelvis's "
            "horizontal travel removed (height and rotations kept); `extract`: a new top "
            "joint `root` at floor level under the pelvis carries the travel and the "
            "facing (yaw) — what Unity's and Unreal's root motion expects."
        ),
    ] = None,
    rig: Annotated[
        int | None,
        Query(
            description="Retarget onto this stored rig (see GET /rigs): its joint names, "
            "hierarchy and rest offsets, every mapped joint turning as the clip's does, "
            "unmapped ones (fingers, face, twist bones) at rest, the travel scaled by the "
            "legs' ratio, feet on the floor."
        ),
    ] = None,
    start: Annotated[
        float | None, Query(description="Cut from here: seconds from the first frame.")
    ] = None,
    end: Annotated[float | None, Query(description="Cut up to here (exclusive), seconds.")] = None,
) -> Response:
    """The uploaded bytes, unchanged; with `format` the clip converted, with `units`, `fps`,
    `root` and `rig` as asked (all combinable, and with `start`/`end`). Without `format`,
    `start` and/or `end` cut the motion: BVH in BVH (same hierarchy, only those frames),
    ASF/AMC as the ASF and the cut AMC (frames renumbered from 1), and FBX/glTF — which
    cannot be cut as they are — as the BVH export of the span. `format=bvh` alone is the BVH
    export the service has always given."""
    options = {"units": units, "fps": fps, "root": root, "rig": rig}
    given = [name for name, value in options.items() if value is not None]
    if file_format is None and given:
        raise InvalidInput(
            f"{given[0]}: needs format=bvh, fbx or glb (without `format` the original upload "
            "is sent as it is)"
        )
    cut = start is not None or end is not None
    if file_format is None and cut and part is None and clip.format in SCENE_FORMATS:
        file_format = "bvh"  # FBX and glTF cannot be cut as they are: the span's BVH export
    if file_format is None:
        download = clip_service.clip_download(library, clip, part, start, end, as_bvh=False)
        return _file_response(download.filename, download.media_type, download.data)
    if part is not None:
        raise InvalidInput(f"part: not with format={file_format} (an export is one file)")
    frames = None
    if start is not None or end is not None:
        frames = span_frames(clip.frame_count, clip.frame_time, 0, start, end)
    # Imported here: the export pipeline (retargeting, root motion, resampling, the GLB
    # writer) is ~70 ms a worker would pay at start-up for a route few requests take.
    from app.services.export import Exporter, ExportOptions

    exporter = Exporter(
        library,
        ExportOptions(format=file_format, units=units, fps=fps, root=root or "keep", rig=rig),
    )
    exported = exporter.export(clip, frames)
    return _file_response(exported.filename, exported.media_type, exported.data)


def _file_response(filename: str, media_type: str, data: bytes) -> Response:
    return Response(
        content=data,
        media_type=media_type,
        headers={"Content-Disposition": _attachment(filename)},
    )


@router.patch(
    "/{clip_id}",
    summary="Rename or relabel a clip",
    dependencies=[WriteAccess],
    responses=error_responses(400, 401, 403, 404, 422, 503),
)
def update_clip(clip: ClipDep, changes: ClipUpdate, library: LibraryDep) -> ClipOut:
    """Change the name, replace the labels, set or clear `source` and `licence`; fields left
    out keep their value."""
    name = normalise_name(changes.name) if changes.name is not None else None
    if changes.name is not None and name is None:
        raise InvalidInput("name: must not be blank")
    labels = normalise_labels(changes.labels) if changes.labels is not None else None
    notes: dict[str, str | None] = {
        key: normalise_note(key, getattr(changes, key))
        for key in ("source", "licence")
        if key in changes.model_fields_set
    }
    return ClipOut.of(
        clip_service.update_clip(library, clip.id, name=name, labels=labels, notes=notes)
    )


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


class DeletedClips(BaseModel):
    deleted: int = Field(description="How many clips were deleted.")
    labels: list[str] = Field(description="The labels the deleted clips carried (all of them).")


@router.delete(
    "",
    summary="Delete every clip carrying a label (or chosen otherwise)",
    dependencies=[WriteAccess],
    responses=error_responses(401, 403, 422, 503),
)
def delete_clips(
    library: LibraryDep,
    label: Annotated[
        list[str] | None,
        Query(
            description="The clips to delete: those carrying this label. "
            + LABEL_FILTER_DOC.split(". ", 1)[1]
        ),
    ] = None,
    licence: LicenceQuery = None,
    q: TextQuery = None,
    clip_ids: Annotated[
        list[int] | None,
        Query(alias="id", description="These clips, by id (repeat `id`).", examples=[[3, 7]]),
    ] = None,
    confirm: Annotated[
        bool,
        Query(description="Must be `true`; without it nothing is deleted (422 with the count)."),
    ] = False,
) -> DeletedClips:
    """Delete, in one transaction, every clip the filters keep — carrying all the `label`s
    given (e.g. the `synthetic` clips `mocap-index fill-synthetic` added), of the `licence`s,
    holding the words of `q`, among the `id`s; at least one of them — with their vectors and
    stored files. Without `confirm=true` nothing is deleted and the answer (422) says how many
    would be."""
    labels = label_filter(label)
    given_labels = None if label is None else labels  # an error names only what was sent
    selection = ClipFilter.of(ids=clip_ids, label=given_labels, licence=licence, q=q)
    if not confirm:
        count = len(clip_service.clips_with_labels(library, selection))
        what = f" labelled {', '.join(labels)}" if labels else ""
        raise InvalidInput(
            f"confirm: this would delete {count} clip{'s' if count != 1 else ''}{what}; add "
            "confirm=true to delete them"
        )
    deleted = clip_service.delete_clips_with(library, selection)
    return DeletedClips(deleted=deleted, labels=list(labels))


def check_page(settings: Settings, limit: int, offset: int) -> None:
    """422 for a page size outside 1..MOCAP_MAX_PAGE_SIZE or a negative offset."""
    if not 1 <= limit <= settings.max_page_size:
        raise InvalidInput(f"limit: must be between 1 and {settings.max_page_size}, got {limit}")
    if offset < 0:
        raise InvalidInput(f"offset: must be ≥ 0, got {offset}")
    if offset > clip_service.MAX_ID:
        raise InvalidInput(f"offset: must be at most {clip_service.MAX_ID}, got {offset}")


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
