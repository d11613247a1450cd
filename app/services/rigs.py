"""Rigs: characters' skeletons that clips are retargeted onto when they are downloaded.

A rig is a skeleton and its reference pose (see :func:`app.motion.retarget.reference_pose`),
mapped by the same structural mapper as clips (a skeleton that is not a whole humanoid is
refused, 422, like a clip). It comes from an uploaded file — BVH, ASF (alone, or as a
``.asf`` file), FBX, glTF/GLB, VRM/VRMA: a character with a mesh and no animation is a rig
(its bind pose is the rest pose), and so is a clip file or a skeleton-only ``Frames: 0`` BVH —
or from a stored clip. FBX and glTF files are read in the parser pool's workers, under the
same time and memory limits as a clip upload; BVH and ASF under the same parse limits.

Rigs live in the database (table ``rigs``), not in the search indexes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import Any

import numpy as np
from sqlalchemy.exc import SQLAlchemyError

from app.db import rigs as rig_repo
from app.db.clips import ClipRecord
from app.errors import (
    InvalidInput,
    LimitExceeded,
    NoAnimation,
    NotFound,
    ParseError,
    StorageUnavailable,
    UnreadableFile,
    UnsupportedMediaType,
)
from app.motion.body import body_height, build_body
from app.motion.formats import decode_text
from app.motion.formats.asf_amc import parse_asf_rest
from app.motion.formats.bvh import parse_bvh, parse_bvh_rest
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton
from app.motion.pipeline import mapping_json
from app.motion.retarget import reference_pose
from app.motion.skeleton_map import SkeletonMap, map_skeleton
from app.motion.units import metres_per_unit
from app.services.describe import read_motion
from app.services.library import Library
from app.services.uploads import clean_filename, normalise_name

# Rig file extensions and the reader each goes to.
RIG_FORMATS = {
    ".bvh": "bvh",
    ".asf": "asf",
    ".fbx": "fbx",
    ".glb": "gltf",
    ".gltf": "gltf",
    ".vrm": "gltf",
    ".vrma": "gltf",
}
ACCEPTED = "supported: .bvh, .asf, .fbx, .glb, .gltf, .vrm or .vrma as 'file'"
MAX_ID = 2**63 - 1


@dataclass(frozen=True, eq=False)
class LoadedRig:
    """A stored rig ready to retarget onto: its one-frame reference pose and mapping."""

    record: rig_repo.RigRecord
    motion: Motion
    mapping: SkeletonMap


def _scene_motion(kind: str, filename: str, data: bytes, library: Library) -> Motion:
    parsers = library.parsers
    if parsers is None:
        raise UnreadableFile(f"file {filename!r}: no FBX/glTF reader here")
    try:
        return parsers.parse(
            f"{kind}-rig", data, animation=None, limits=library.settings.parse_limits
        ).motion
    except (ParseError, LimitExceeded, UnreadableFile) as error:
        detail = error.reason if isinstance(error, ParseError) else error.detail
        raise type(error)(f"file {filename!r}: {detail}") from None


def read_rig_file(library: Library, filename: str, data: bytes) -> tuple[str, Motion]:
    """``(format, motion)`` of an uploaded rig file: a clip's motion, or for a file without
    animation its rest pose as one frame."""
    suffix = PurePosixPath(filename).suffix.lower()
    kind = RIG_FORMATS.get(suffix)
    if kind is None:
        raise UnsupportedMediaType(f"field 'file': {filename!r} is not a rig file ({ACCEPTED})")
    if not data:
        raise InvalidInput(f"field 'file': the file {filename!r} is empty")
    limits = library.settings.parse_limits
    if kind in ("fbx", "gltf"):
        return kind, _scene_motion(kind, filename, data, library)
    try:
        text = decode_text(data)
        if kind == "asf":
            return "asf/amc", parse_asf_rest(text, limits=limits)
        try:
            return "bvh", parse_bvh(text, limits=limits)
        except NoAnimation:  # Frames: 0, or no MOTION section: the skeleton is the rig
            return "bvh", parse_bvh_rest(text, limits=limits)
    except ParseError as error:
        raise ParseError(error.reason, line=error.line, source=f"file {filename!r}") from None
    except LimitExceeded as error:
        raise LimitExceeded(f"file {filename!r}: {error.detail}") from None


def _rig_of(motion: Motion) -> tuple[Motion, SkeletonMap]:
    """The rig (reference pose, one frame) of any read motion, and its mapping."""
    try:
        body = build_body(motion)
    except ParseError as error:
        raise type(error)(error.reason) from None
    assert body.mapping is not None
    rig = reference_pose(motion, body.mapping)
    return rig, _map_rig(rig)


def _map_rig(rig: Motion) -> SkeletonMap:
    _, positions = forward_kinematics(rig)
    return map_skeleton(rig.skeleton, poses=[("frame 0", positions[0])])


def _skeleton_json(rig: Motion) -> dict[str, Any]:
    skeleton = rig.skeleton
    return {
        "names": list(skeleton.names),
        "parents": skeleton.parents.tolist(),
        "offsets": skeleton.offsets.tolist(),
        "end_site": skeleton.end_site.tolist(),
        "rotations": rig.local_rotations[0].reshape(-1, 9).tolist(),
        "root": rig.root_translation[0].tolist(),
        "frame_time": rig.frame_time,
        "source_format": rig.source_format,
    }


def _motion_of(skeleton: dict[str, Any], length_unit: str) -> Motion:
    count = len(skeleton["names"])
    return Motion(
        skeleton=Skeleton(
            names=tuple(skeleton["names"]),
            parents=np.asarray(skeleton["parents"], dtype=np.int64),
            offsets=np.asarray(skeleton["offsets"], dtype=np.float64).reshape(count, 3),
            end_site=np.asarray(skeleton["end_site"], dtype=bool),
        ),
        frame_time=float(skeleton["frame_time"]),
        root_translation=np.asarray(skeleton["root"], dtype=np.float64).reshape(1, 3),
        local_rotations=np.asarray(skeleton["rotations"], dtype=np.float64).reshape(1, count, 3, 3),
        source_format=str(skeleton.get("source_format", "bvh")),
        length_unit=length_unit,
    )


def _store(library: Library, name: str, filename: str, source_format: str, motion: Motion) -> int:
    rig, mapping = _rig_of(motion)
    height = body_height(rig, mapping.joints, head_joint=mapping.head_joint)
    new = rig_repo.NewRig(
        name=name,
        format=source_format,
        filename=filename,
        joint_count=rig.skeleton.joint_count,
        skeleton_family=mapping.family,
        length_unit=rig.length_unit,
        metres_per_unit=metres_per_unit(rig.source_format, height),
        skeleton=_skeleton_json(rig),
        joint_mapping=mapping_json(mapping, rig.skeleton.names),
    )
    try:
        with library.writes.begin() as session:
            return rig_repo.insert_rig(session, new)
    except SQLAlchemyError as exc:
        raise StorageUnavailable(f"cannot write to the database: {exc}") from exc


def create_rig(library: Library, filename: str | None, data: bytes, name: str | None) -> int:
    """Store the rig of an uploaded file; its id."""
    clean = clean_filename(filename, "file")
    source_format, motion = read_rig_file(library, clean, data)
    label = normalise_name(name) or PurePosixPath(clean).stem or clean
    return _store(library, label, clean, source_format, motion)


def create_rig_from_clip(library: Library, clip: ClipRecord, name: str | None) -> int:
    """Store a stored clip's skeleton as a rig; its id."""
    from app.services.clips import stored_upload

    upload = stored_upload(library, clip)
    motion = read_motion(upload, library.settings.parse_limits, library.parsers).motion
    filename = upload.parts[-1].filename
    return _store(library, normalise_name(name) or clip.name, filename, clip.format, motion)


def get_rig(library: Library, rig_id: int, *, field: str | None = None) -> rig_repo.RigRecord:
    """The rig ``rig_id`` (404, or 422 naming ``field`` when it is a parameter's value)."""
    found = None
    if 0 < rig_id <= MAX_ID:
        with library.reads() as session:
            found = rig_repo.get_rig(session, rig_id)
    if found is None:
        if field is not None:
            raise InvalidInput(f"{field}: no rig with id {rig_id} (see GET /rigs)")
        raise NotFound(f"no rig with id {rig_id}")
    return found


def list_rigs(library: Library, *, limit: int, offset: int) -> tuple[list[rig_repo.RigRecord], int]:
    with library.reads() as session:
        return rig_repo.list_rigs(session, limit=limit, offset=offset)


def delete_rig(library: Library, rig_id: int) -> None:
    try:
        with library.writes.begin() as session:
            found = 0 < rig_id <= MAX_ID and rig_repo.delete_rig(session, rig_id)
    except SQLAlchemyError as exc:
        raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
    if not found:
        raise NotFound(f"no rig with id {rig_id}")


def load_rig(record: rig_repo.RigRecord) -> LoadedRig:
    """A stored rig as the motion core's objects (mapped again, a few milliseconds: the
    mapper keeps what the skeleton's tree decides)."""
    motion = _motion_of(record.skeleton, record.length_unit)
    return LoadedRig(record, motion, _map_rig(motion))


def rest_figure(record: rig_repo.RigRecord) -> dict[str, Any]:
    """The rig's joints in its reference pose, for drawing: names, parents and world
    positions ``(J, 3)`` in the rig's units."""
    motion = _motion_of(record.skeleton, record.length_unit)
    _, positions = forward_kinematics(motion)
    return {
        "names": list(motion.skeleton.names),
        "parents": motion.skeleton.parents.tolist(),
        "positions": np.round(positions[0], 6).tolist(),
    }


__all__ = [
    "LoadedRig",
    "create_rig",
    "create_rig_from_clip",
    "delete_rig",
    "get_rig",
    "list_rigs",
    "load_rig",
    "read_rig_file",
    "rest_figure",
]
