"""Request and response bodies of the API (they define the OpenAPI schema)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from app.db.clip_filters import ClipFilter
from app.db.clips import AnimationRecord, ClipRecord, NewClip
from app.db.vectors import StoredVector
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
    "source": "Bandai Namco Research Motiondataset",
    "licence": "CC BY-NC-ND 4.0",
    "created_at": "2026-11-22T10:15:00Z",
}


class ClipFields(BaseModel):
    """What is known about a clip's content."""

    name: str = Field(
        description="Display name; by default the (motion) file name without extension."
    )
    filenames: list[str] = Field(
        description=(
            "Original file names: one .bvh/.fbx/.glb/.gltf/.vrma/.vrm, or the .asf and .amc."
        )
    )
    format: str = Field(description='"bvh", "asf/amc", "fbx" or "gltf".')
    content_hash: str = Field(
        description=(
            "sha256 of the uploaded bytes (ASF/AMC: sha256 of sha256(asf) + sha256(amc); "
            "FBX/glTF: sha256 of sha256(file), a newline and the animation's name)."
        )
    )
    frame_count: int = Field(description="Frames in the file.")
    frame_time: float = Field(description="Seconds per frame.")
    duration: float = Field(description="Seconds covered by the clip.")
    joint_count: int = Field(
        description="Joints of the skeleton, end sites (bone tips) not counted; clips stored "
        "before this was fixed count them until `mocap-index reindex --all`."
    )
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
    labels: list[str] = Field(
        description="Free-form tags, each once whatever its case (the first spelling is kept)."
    )
    source: str | None = Field(default=None, description="Where the clip comes from, if given.")
    licence: str | None = Field(
        default=None, description="Under which terms the clip may be used, if given."
    )
    animations: list[AnimationOut] | None = Field(
        default=None,
        exclude_if=lambda value: value is None,
        description=(
            "FBX/glTF: every animation of the file (the clip holds the one marked "
            "`selected`); absent for BVH and ASF/AMC."
        ),
    )


class AnimationOut(BaseModel):
    """One animation of an FBX/glTF file."""

    name: str = Field(description="As the file names it (`animation N` when it does not).")
    frame_count: int = Field(description="Frames at the rate it is sampled at.")
    duration: float = Field(
        description="Seconds its frames cover (`frame_count` / its rate): the clip's own "
        "`duration` for the selected one."
    )
    selected: bool = Field(description="Whether this clip holds this animation.")

    @classmethod
    def of(cls, record: AnimationRecord) -> AnimationOut:
        return cls(
            name=record.name,
            frame_count=record.frame_count,
            duration=record.duration,
            selected=record.selected,
        )


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
    duplicate: bool | None = Field(
        default=None,
        exclude_if=lambda value: value is None,
        description="Only in the answer to an upload: true when the content was already stored "
        "(status 200; the labels, name, source and licence sent were applied to that clip).",
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
        duplicate: bool | None = None,
        mapping: bool = False,
    ) -> ClipOut:
        return cls(
            **_clip_fields(clip),
            id=clip.id,
            created_at=clip.created_at,
            duplicate=duplicate,
            mapping=dict(clip.joint_mapping or {}) if mapping else None,
            descriptors=None
            if vectors is None
            else {
                name: DescriptorVector(version=v.version, vector=v.vector.tolist())
                for name, v in vectors.items()
            },
        )


class StoredClipRef(BaseModel):
    """A stored clip, by id and name."""

    id: int
    name: str


class UploadedClipOut(ClipFields):
    """An uploaded query clip (described, not stored: it has no id)."""

    stored_clip: StoredClipRef | None = Field(
        default=None,
        description="The stored clip with this very content (same content hash), when there "
        "is one: the file is already in the library as that clip (which a search then finds "
        "at distance 0). Null otherwise.",
    )

    @classmethod
    def of(cls, clip: NewClip, stored: ClipRecord | None = None) -> UploadedClipOut:
        return cls(
            **_clip_fields(clip),
            stored_clip=None if stored is None else StoredClipRef(id=stored.id, name=stored.name),
        )


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
        "source": clip.source,
        "licence": clip.licence,
        "animations": None
        if clip.animations is None
        else [AnimationOut.of(a) for a in clip.animations],
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
    labels: list[str] | None = Field(
        default=None,
        description="Replaces every label (split on commas, trimmed, case-insensitive "
        "duplicates dropped).",
    )
    source: str | None = Field(
        default=None, max_length=500, description="Where the clip comes from; null or '' clears."
    )
    licence: str | None = Field(
        default=None, max_length=500, description="Terms of use; null or '' clears."
    )


# Ids one bulk request may name (a selection by label, licence or text has no bound).
MAX_SELECTED_IDS = 100_000


class ClipSelection(BaseModel):
    """Which clips: those matching every criterion given (at least one, or `all`)."""

    model_config = ConfigDict(extra="forbid")

    ids: list[int] | None = Field(
        default=None, max_length=MAX_SELECTED_IDS, description="These clips (by id)."
    )
    label: list[str] | None = Field(
        default=None, description="Clips carrying all these labels (any case)."
    )
    licence: list[str] | None = Field(
        default=None, description="Clips of these licences; `!` in front leaves one out."
    )
    q: str | None = Field(default=None, description="Clips holding every word, as `GET /clips?q=`.")
    all: bool = Field(default=False, description="Every clip (when nothing else is given).")

    def selection(self) -> ClipFilter:
        return ClipFilter.of(ids=self.ids, label=self.label, licence=self.licence, q=self.q)


class LabelChanges(ClipSelection):
    """Labels to add to and remove from a set of clips."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"ids": [3, 7, 12], "add": ["jump"], "remove": ["todo"]},
                {"q": "cmu walk", "licence": ["!CC BY-NC 4.0"], "add": ["shippable"]},
            ]
        },
    )

    add: list[str] = Field(default=[], description="Labels every selected clip then carries.")
    remove: list[str] = Field(
        default=[], description="Labels no selected clip then carries (any case)."
    )


class LabelsChanged(BaseModel):
    matched: int = Field(description="Clips the selection kept.")
    changed: int = Field(description="Of those, clips whose labels changed.")
    added: list[str] = Field(description="The labels added (as normalised).")
    removed: list[str] = Field(description="The labels removed.")


SIMILARITY_DOC = (
    "How similar, in percent: the share of the library's typical neighbour distances under "
    "this descriptor (each of a sample of clips to its 10 nearest others) that are larger than "
    "this result's distance. 97: nearer than 97 % of them; 50: as near as a typical neighbour."
)


class OtherFile(BaseModel):
    """A near-identical clip a collapsed result stands for."""

    id: int
    name: str
    format: str
    filenames: list[str]
    distance: float

    @classmethod
    def of(cls, hit: Hit) -> OtherFile:
        clip = hit.clip
        return cls(
            id=clip.id,
            name=clip.name,
            format=clip.format,
            filenames=list(clip.filenames),
            distance=hit.distance,
        )


OTHERS_DOC = (
    "Only with `collapse=capture`: the other clips near-identical to this one (the same "
    "capture in other files or formats), which take no place of their own: "
    '"+2 other files of this capture".'
)


class SearchHit(BaseModel):
    id: int
    name: str
    labels: list[str]
    format: str = Field(description='"bvh", "asf/amc" (or "synthetic"): same-named clips differ.')
    filenames: list[str] = Field(description="Original file names.")
    skeleton_family: str = Field(description="Naming convention the skeleton was matched as.")
    distance: float = Field(description="Euclidean distance between the descriptor vectors.")
    similarity: float = Field(description=SIMILARITY_DOC)
    others: list[OtherFile] | None = Field(
        default=None, exclude_if=lambda value: value is None, description=OTHERS_DOC
    )

    @classmethod
    def of(cls, hit: Hit, *, collapsed: bool = False) -> SearchHit:
        clip = hit.clip
        return cls(
            id=clip.id,
            name=clip.name,
            labels=list(clip.labels),
            format=clip.format,
            filenames=list(clip.filenames),
            skeleton_family=clip.skeleton_family,
            distance=hit.distance,
            similarity=hit.similarity,
            others=[OtherFile.of(o) for o in hit.others] if collapsed else None,
        )


_HITS_EXAMPLE: list[Any] = [
    {
        "id": 12,
        "name": "dataset-1_walk_sad_001",
        "labels": ["walk"],
        "format": "bvh",
        "filenames": ["dataset-1_walk_sad_001.bvh"],
        "skeleton_family": "bandai",
        "distance": 0.0123,
        "similarity": 96.4,
    },
    {
        "id": 31,
        "name": "dataset-1_walk_proud_001",
        "labels": ["walk"],
        "format": "bvh",
        "filenames": ["dataset-1_walk_proud_001.bvh"],
        "skeleton_family": "bandai",
        "distance": 0.0201,
        "similarity": 91.0,
    },
]


class ClipSearchResponse(BaseModel):
    """Nearest clips to a stored clip, nearest first (the query clip itself excluded)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"query": _CLIP_EXAMPLE, "descriptor": "motion", "k": 2, "results": _HITS_EXAMPLE}
            ]
        }
    )

    query: ClipOut
    descriptor: str
    k: int
    results: list[SearchHit]
    query_others: list[OtherFile] | None = Field(
        default=None,
        exclude_if=lambda value: value is None,
        description="Only with `collapse=capture`: clips near-identical to the query clip "
        "(its own capture in other files), left out of `results`.",
    )


class UploadSearchResponse(BaseModel):
    """Nearest clips to an uploaded file, nearest first (nothing excluded)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "query": {
                        k: v for k, v in _CLIP_EXAMPLE.items() if k not in ("id", "created_at")
                    },
                    "descriptor": "motion",
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
                    "default": "motion",
                    "descriptors": [
                        {
                            "name": "posture",
                            "dimension": 12,
                            "version": 2,
                            "description": "How the body is held: how spread out, tall or "
                            "leaning the pose is on average and how much it varies.",
                        }
                    ],
                }
            ]
        }
    )

    default: str = Field(description="The descriptor a search uses when none is named.")
    descriptors: list[DescriptorOut]


class IndexHealth(BaseModel):
    size: int = Field(
        description="Vectors in this server's index, brought up to date with the database "
        "(clips another process stored included) when /health is asked."
    )
    dimension: int
    version: int
    missing: int = Field(
        description="Clips with no vector of this version in the database: no search with this "
        "descriptor finds them until `mocap-index reindex` computes it."
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
