"""Request and response bodies of the API (they define the OpenAPI schema)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from app.db.repository import ClipRecord, NewClip, StoredVector
from app.services.describe import DescriptorInfo
from app.services.search import Hit

_CLIP_EXAMPLE: dict[str, Any] = {
    "id": 7,
    "name": "dataset-1_walk_happy_001",
    "filenames": ["dataset-1_walk_happy_001.bvh"],
    "format": "bvh",
    "content_hash": "9f2c4e1b8a7d6c5e4f3a2b1c0d9e8f7a6b5c4d3e2f1a0b9c8d7e6f5a4b3c2d1e",
    "frame_count": 312,
    "frame_time": 0.0333333,
    "duration": 10.4,
    "joint_count": 27,
    "skeleton_family": "bandai",
    "lead_in_frames": 0,
    "warnings": [],
    "labels": ["walk", "happy"],
    "created_at": "2026-11-22T10:15:00Z",
}


class ClipFields(BaseModel):
    """What is known about a clip's content."""

    name: str = Field(
        description="Display name; by default the (motion) file name without extension."
    )
    filenames: list[str] = Field(description="Original file names: one .bvh, or the .asf and .amc.")
    format: str = Field(description='"bvh" or "asf/amc".')
    content_hash: str = Field(
        description="sha256 of the uploaded bytes (ASF/AMC: sha256 of sha256(asf) + sha256(amc))."
    )
    frame_count: int = Field(description="Frames in the file.")
    frame_time: float = Field(description="Seconds per frame.")
    duration: float = Field(description="Seconds covered by the clip.")
    joint_count: int = Field(description="Joints of the skeleton, end sites included.")
    skeleton_family: str = Field(description="Naming convention the skeleton was matched as.")
    lead_in_frames: int = Field(
        description="Rest-pose frames at the start left out of the descriptors."
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="Short sentences about what reading the file had to repair or decide "
        '("mirrored capture: stored un-mirrored", "neck derived from the head\'s parent", '
        '"3 short lines after the last frame ignored", ...).',
    )
    labels: list[str] = Field(description="Free-form tags.")


class DescriptorVector(BaseModel):
    version: int = Field(description="Descriptor version that computed the vector.")
    vector: list[float] = Field(description="The descriptor's numbers.")


class ClipOut(ClipFields):
    """A stored clip."""

    model_config = ConfigDict(json_schema_extra={"examples": [_CLIP_EXAMPLE]})

    id: int = Field(description="Clip id.")
    created_at: datetime = Field(description="When the clip was stored (UTC).")
    descriptors: dict[str, DescriptorVector] | None = Field(
        default=None,
        exclude_if=lambda value: value is None,
        description="Every stored descriptor vector by name; only with `?include=descriptors`.",
    )
    mapping: dict[str, Any] | None = Field(
        default=None,
        exclude_if=lambda value: value is None,
        description="Only with `?include=mapping`: `joints` maps each canonical joint to "
        '`{"joint": source joint name, "how": how it was found}`; `end_sites` lists the '
        "canonical points that are end effectors; `pose` says whether the rest pose or a "
        "frame showed the body; `mirrored` whether the capture was stored un-mirrored. "
        "Empty for clips stored before the mapping was recorded.",
    )

    @classmethod
    def of(
        cls,
        clip: ClipRecord,
        vectors: dict[str, StoredVector] | None = None,
        *,
        mapping: bool = False,
    ) -> ClipOut:
        return cls(
            **_clip_fields(clip),
            id=clip.id,
            created_at=clip.created_at,
            mapping=dict(clip.joint_mapping or {}) if mapping else None,
            descriptors=None
            if vectors is None
            else {
                name: DescriptorVector(version=v.version, vector=v.vector.tolist())
                for name, v in vectors.items()
            },
        )


class UploadedClipOut(ClipFields):
    """An uploaded query clip (described, not stored: it has no id)."""

    @classmethod
    def of(cls, clip: NewClip) -> UploadedClipOut:
        return cls(**_clip_fields(clip))


def _clip_fields(clip: ClipRecord | NewClip) -> dict[str, Any]:
    """The fields a stored clip and a described upload share, as :class:`ClipFields` takes them."""
    return {
        "name": clip.name,
        "filenames": [f.filename for f in clip.files],
        "format": clip.format,
        "content_hash": clip.content_hash,
        "frame_count": clip.frame_count,
        "frame_time": clip.frame_time,
        "duration": clip.duration,
        "joint_count": clip.joint_count,
        "skeleton_family": clip.skeleton_family,
        "lead_in_frames": clip.lead_in_frames,
        "warnings": list(clip.warnings),
        "labels": list(clip.labels),
    }


class ClipPage(BaseModel):
    """One page of clips in id order."""

    total: int = Field(description="Clips matching the filter, over all pages.")
    limit: int
    offset: int
    items: list[ClipOut]


class ClipUpdate(BaseModel):
    """Fields to change; those left out keep their value."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"name": "happy walk", "labels": ["walk", "happy"]}]},
    )

    name: str | None = Field(default=None, min_length=1, max_length=255)
    labels: list[str] | None = Field(default=None, description="Replaces every label.")


class SearchHit(BaseModel):
    id: int
    name: str
    labels: list[str]
    distance: float = Field(description="Euclidean distance between the descriptor vectors.")

    @classmethod
    def of(cls, hit: Hit) -> SearchHit:
        return cls(
            id=hit.clip.id, name=hit.clip.name, labels=list(hit.clip.labels), distance=hit.distance
        )


_HITS_EXAMPLE: list[Any] = [
    {"id": 12, "name": "dataset-1_walk_sad_001", "labels": ["walk"], "distance": 0.0123},
    {"id": 31, "name": "dataset-1_walk_proud_001", "labels": ["walk"], "distance": 0.0201},
]


class ClipSearchResponse(BaseModel):
    """Nearest clips to a stored clip, nearest first (the query clip itself excluded)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"query": _CLIP_EXAMPLE, "descriptor": "posture", "k": 2, "results": _HITS_EXAMPLE}
            ]
        }
    )

    query: ClipOut
    descriptor: str
    k: int
    results: list[SearchHit]


class UploadSearchResponse(BaseModel):
    """Nearest clips to an uploaded file, nearest first (nothing excluded)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "query": {
                        k: v for k, v in _CLIP_EXAMPLE.items() if k not in ("id", "created_at")
                    },
                    "descriptor": "posture",
                    "k": 2,
                    "results": _HITS_EXAMPLE,
                }
            ]
        }
    )

    query: UploadedClipOut
    descriptor: str
    k: int
    results: list[SearchHit]


class DescriptorOut(BaseModel):
    name: str
    dimension: int
    version: int
    description: str

    @classmethod
    def of(cls, info: DescriptorInfo) -> DescriptorOut:
        return cls(
            name=info.name,
            dimension=info.dimension,
            version=info.version,
            description=info.description,
        )


class DescriptorList(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "default": "posture",
                    "descriptors": [
                        {
                            "name": "posture",
                            "dimension": 12,
                            "version": 1,
                            "description": "Posture variation: mean and std of joint covariance.",
                        }
                    ],
                }
            ]
        }
    )

    default: str = Field(description="The descriptor a search uses when none is named.")
    descriptors: list[DescriptorOut]


class IndexHealth(BaseModel):
    size: int = Field(description="Vectors in the index.")
    dimension: int
    version: int
    missing: int = Field(
        description="Clips without a vector of this version (found after `mocap-index reindex`)."
    )


class Health(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "status": "ok",
                    "clips": 174,
                    "indexes": {
                        "posture": {"size": 174, "dimension": 12, "version": 1, "missing": 0}
                    },
                }
            ]
        }
    )

    status: str
    clips: int
    indexes: dict[str, IndexHealth]
