"""/rigs: characters' skeletons that clips are retargeted onto (``GET /clips/{id}/file?rig=``)."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any

from fastapi import APIRouter, Depends, File, Form, Query, Request, Response, UploadFile, status
from pydantic import BaseModel, Field

from app.api.auth import WriteAccess
from app.api.clips import check_page
from app.api.deps import LibraryDep, SettingsDep, single_valued
from app.api.errors import error_responses
from app.api.query_check import CheckedQueryRoute
from app.errors import InvalidInput, UnsupportedMediaType
from app.motion.units import unit_name
from app.services import clips as clip_service
from app.services.uploads import clean_filename, packed_file, split_files

if TYPE_CHECKING:
    from app.db.rigs import RigRecord

# app.services.rigs (with the retargeting it needs, ~30 ms) is imported inside the routes that
# use it, so that a worker starts without it: rigs are stored and read by few requests.

router = APIRouter(prefix="/rigs", tags=["rigs"], route_class=CheckedQueryRoute)


class RigOut(BaseModel):
    """A stored rig."""

    id: int = Field(description="Rig id: the value of `rig=` on a download.")
    name: str = Field(description="The rig's name (the file name without extension by default).")
    format: str = Field(description="The format it was read from: bvh, asf/amc, fbx or gltf.")
    filename: str = Field(description="The uploaded file's name (or the clip's file).")
    joint_count: int = Field(description="Joints of the skeleton, end sites included.")
    skeleton_family: str = Field(description="The naming convention recognised.")
    units: str = Field(
        description="The skeleton's length unit (`cm`, `m`, `in`...): what BVH and FBX "
        "downloads on this rig are in by default (centimetres for FBX and glTF rigs)."
    )
    created_at: datetime = Field(description="When the rig was stored (UTC).")
    mapping: dict[str, Any] | None = Field(
        default=None,
        exclude_if=lambda value: value is None,
        description="Which of the rig's joints is each canonical joint and how it was found, "
        "in the shape of a clip's `?include=mapping` (`joints`, `end_sites`, `pose`, "
        "`mirrored`); in `GET /rigs/{id}` and the answer to an upload.",
    )
    skeleton: dict[str, Any] | None = Field(
        default=None,
        exclude_if=lambda value: value is None,
        description="The rig in its rest pose, for drawing: `names`, `parents` (index, -1 at "
        "the top) and `positions` (x, y, z per joint, in the rig's units); with the mapping.",
    )

    @classmethod
    def of(cls, rig: RigRecord, *, details: bool = False) -> RigOut:
        from app.services import rigs as rig_service

        return cls(
            id=rig.id,
            name=rig.name,
            format=rig.format,
            filename=rig.filename,
            joint_count=rig.joint_count,
            skeleton_family=rig.skeleton_family,
            units=unit_name(0.01 if rig.format in ("fbx", "gltf") else rig.metres_per_unit),
            created_at=rig.created_at,
            mapping=dict(rig.joint_mapping) if details else None,
            skeleton=rig_service.rest_figure(rig) if details else None,
        )


class RigPage(BaseModel):
    total: int = Field(description="How many rigs are stored.")
    limit: int
    offset: int
    items: list[RigOut]


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    summary="Store a rig",
    dependencies=[WriteAccess, Depends(single_valued("name"))],
    responses=error_responses(400, 401, 403, 404, 413, 415, 422, 503),
)
def create_rig(
    request: Request,
    library: LibraryDep,
    response: Response,
    file: Annotated[
        list[UploadFile] | None,
        File(
            description="A character's skeleton: BVH (`.bvh`, `Frames: 0` skeletons too), "
            "Acclaim skeleton (`.asf`), FBX (`.fbx`), glTF (`.glb`, or `.gltf`: repeat the "
            "field for the files it refers to), VRM (`.vrm`) or VRM animation (`.vrma`). A "
            "file with a mesh and no animation is a rig (its bind pose is the rest pose); a "
            "clip file works too."
        ),
    ] = None,
    name: Annotated[str | None, Form(description="Rig name; default: the file's name.")] = None,
    from_clip: Annotated[
        int | None,
        Query(description="Instead of a file: use this stored clip's skeleton as a rig."),
    ] = None,
) -> RigOut:
    """Store a rig, mapped by the same structural mapper as clips (a skeleton that is not a
    whole humanoid gets 422 like a clip); the answer shows the mapping. Read under the same
    limits as a clip upload (FBX and glTF in the isolated reader processes)."""
    from app.services import rigs as rig_service

    if from_clip is not None:
        if file is not None:
            raise InvalidInput("file: send a file or from_clip, not both")
        clip = clip_service.get_clip(library, from_clip)
        rig_id = rig_service.create_rig_from_clip(library, clip, name)
    else:
        content_type = request.headers.get("content-type", "")
        if not content_type.lower().startswith("multipart/form-data"):
            raise UnsupportedMediaType(
                "send the rig as multipart/form-data with the file in 'file' (got "
                f"{content_type or 'no content type'!r}), or use ?from_clip="
            )
        main, resources = split_files(
            [(part.filename, part.file.read()) for part in file or []], rig_service.RIG_FORMATS
        )
        if main is None:
            raise InvalidInput("field 'file': no upload; send a rig file as 'file'")
        filename, data = packed_file(clean_filename(main[0], "file"), main[1], resources)
        rig_id = rig_service.create_rig(library, filename, data, name)
    response.headers["Location"] = f"/rigs/{rig_id}"
    return RigOut.of(rig_service.get_rig(library, rig_id), details=True)


@router.get("", summary="List rigs", responses=error_responses(422, 503))
def list_rigs(
    library: LibraryDep,
    settings: SettingsDep,
    limit: Annotated[int, Query(description="Page size, 1 to MOCAP_MAX_PAGE_SIZE.")] = 50,
    offset: Annotated[int, Query(description="Rigs to skip (≥ 0).")] = 0,
) -> RigPage:
    """Rigs in id order, a page at a time, with the total count (what a rig picker lists)."""
    from app.services import rigs as rig_service

    check_page(settings, limit, offset)
    items, total = rig_service.list_rigs(library, limit=limit, offset=offset)
    return RigPage(total=total, limit=limit, offset=offset, items=[RigOut.of(r) for r in items])


@router.get("/{rig_id}", summary="Get a rig", responses=error_responses(404, 422, 503))
def get_rig(rig_id: int, library: LibraryDep) -> RigOut:
    """One rig, with its mapping and its rest-pose skeleton."""
    from app.services import rigs as rig_service

    return RigOut.of(rig_service.get_rig(library, rig_id), details=True)


@router.delete(
    "/{rig_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a rig",
    dependencies=[WriteAccess],
    response_class=Response,
    responses=error_responses(401, 403, 404, 422, 503),
)
def delete_rig(rig_id: int, library: LibraryDep) -> Response:
    """Remove the rig (clips are not touched)."""
    from app.services import rigs as rig_service

    rig_service.delete_rig(library, rig_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
