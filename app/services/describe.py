"""From uploaded bytes to what is stored about a clip, through the motion core.

The service talks to the motion core only through a :class:`Describer`, so storage, indexes
and the API are generic over the descriptor registry (and testable with synthetic vectors).
:class:`MotionDescriber` is the real one: read (:func:`read_motion`: BVH and ASF/AMC here,
FBX and glTF in parser worker processes) -> ``analyse``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from app.errors import DescribeTimeout, InvalidInput, LimitExceeded, ParseError, UnreadableFile
from app.motion.descriptors import REGISTRY
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.scene import Animation
from app.motion.model import Motion, ParseLimits
from app.motion.pipeline import analyse
from app.services.parser_pool import SceneParser
from app.services.uploads import ASF_AMC, BVH, Upload

if TYPE_CHECKING:
    from app.config import Settings


@dataclass(frozen=True)
class DescriptorInfo:
    """A descriptor as the service sees it: vectors of ``dimension`` float32 numbers, compared
    with the Euclidean distance; ``version`` changes whenever the numbers change."""

    name: str
    dimension: int
    version: int
    description: str


@dataclass(frozen=True)
class Description:
    """What the motion core measured on one clip; ``vectors[name]`` is ``(D,)`` float32."""

    frame_count: int
    frame_time: float
    duration: float
    joint_count: int
    skeleton_family: str
    lead_in_frames: int
    vectors: dict[str, np.ndarray]
    animation: str | None = None  # FBX/glTF: the animation described
    animations: tuple[Animation, ...] = ()  # FBX/glTF: every animation of the file
    warnings: tuple[str, ...] = ()
    joint_mapping: dict[str, object] | None = None

    @property
    def fields(self) -> dict[str, object]:
        """The measured clip fields (everything but the vectors), by column name."""
        return {
            "frame_count": self.frame_count,
            "frame_time": self.frame_time,
            "duration": self.duration,
            "joint_count": self.joint_count,
            "skeleton_family": self.skeleton_family,
            "lead_in_frames": self.lead_in_frames,
            "warnings": json.dumps(list(self.warnings)),
            "joint_mapping": None if self.joint_mapping is None else json.dumps(self.joint_mapping),
        }


class Describer(Protocol):
    @property
    def descriptors(self) -> Mapping[str, DescriptorInfo]:
        """Every available descriptor, by name, in a stable order."""
        ...

    def describe(
        self, upload: Upload, limits: ParseLimits, *, only: Sequence[str] | None = None
    ) -> Description:
        """Parse and describe ``upload`` under every descriptor (or those in ``only``).

        Raises ParseError / LimitExceeded / InvalidInput for input that cannot be described.
        """
        ...


def check_vectors(
    vectors: Mapping[str, np.ndarray], descriptors: Mapping[str, DescriptorInfo]
) -> dict[str, np.ndarray]:
    """Vectors as ``(D,)`` float32 C-contiguous, checked against their descriptors.

    A non-finite or mis-shaped vector would poison the index, so the clip is refused (422).
    """
    checked = {}
    for name, vector in vectors.items():
        info = descriptors[name]
        array = np.ascontiguousarray(vector, dtype=np.float32).reshape(-1)
        if array.shape != (info.dimension,):
            raise InvalidInput(
                f"descriptor {name!r} produced {array.size} numbers, expected {info.dimension}"
            )
        if not np.all(np.isfinite(array)):
            raise InvalidInput(
                f"the clip cannot be described: descriptor {name!r} is not finite (degenerate "
                "motion, e.g. a skeleton of zero size)"
            )
        checked[name] = array
    return checked


def _part_of(upload: Upload, source: str | None) -> Any:
    """The uploaded part a parser's message is about (``source`` "ASF"/"AMC" or None)."""
    if upload.format != ASF_AMC:
        return upload.parts[0]
    role = {"ASF": "skeleton", "AMC": "motion"}.get(source or "")
    return upload.part(role) if role is not None else None


def _name_limit_source(error: LimitExceeded, upload: Upload) -> LimitExceeded:
    """A limit the parser hit, saying which uploaded field and file it is about."""
    part = _part_of(upload, "ASF" if error.detail.startswith("ASF") else "AMC")
    return LimitExceeded(f"{part.role} {part.filename!r}: {error.detail}")


def _name_source(error: ParseError, upload: Upload) -> ParseError:
    """The parser's error, saying which uploaded field and file it is about."""
    part = _part_of(upload, error.source)
    if part is None:
        return error
    return type(error)(error.reason, line=error.line, source=f"{part.role} {part.filename!r}")


@dataclass(frozen=True, eq=False)
class ReadMotion:
    """An upload read: its motion, and for FBX/glTF the animation read and every one."""

    motion: Motion
    animation: str | None = None
    animations: tuple[Animation, ...] = ()


def read_motion(upload: Upload, limits: ParseLimits, parsers: SceneParser | None) -> ReadMotion:
    """Read an upload's motion: BVH and ASF/AMC in this process, FBX and glTF in a worker
    of ``parsers`` (the one way every part of the service reads a clip).

    Raises ParseError / LimitExceeded naming the uploaded field and file, and UnreadableFile
    when a worker crashed, hung or ran out of memory.
    """
    try:
        if upload.format == BVH:
            return ReadMotion(read_bvh(upload.parts[0].data, limits=limits))
        if upload.format == ASF_AMC:
            return ReadMotion(
                read_asf_amc(
                    upload.part("skeleton").data, upload.part("motion").data, limits=limits
                )
            )
        part = upload.parts[0]
        if parsers is None:
            raise UnreadableFile(f"{part.role} {part.filename!r}: no FBX/glTF reader here")
        try:
            parsed = parsers.parse(
                upload.format, part.data, animation=upload.animation, limits=limits
            )
        except UnreadableFile as error:
            raise UnreadableFile(f"{part.role} {part.filename!r}: {error.detail}") from None
        return ReadMotion(parsed.motion, parsed.animation, parsed.animations)
    except ParseError as error:
        raise _name_source(error, upload) from None
    except LimitExceeded as error:
        raise _name_limit_source(error, upload) from None


class MotionDescriber:
    """The real describer: :mod:`app.motion` parsers, ``analyse`` and its ``REGISTRY``.

    Parameters
    ----------
    time_limit:
        Seconds one :meth:`describe` may take, or ``None``. Checked between the stages (parse,
        then kinematics and descriptors); each stage's work is bounded by the parse limits, so
        a request overruns the limit by at most one bounded stage. Past it:
        :class:`~app.errors.DescribeTimeout` (503).
    max_values:
        Cap on ``ParseLimits.max_values`` (numbers the frames may expand to), whatever limits
        the caller passes: it bounds the memory one clip takes, which the byte size of an
        upload does not (joints without channels cost memory but no bytes).
    """

    def __init__(
        self,
        *,
        time_limit: float | None = None,
        max_values: int | None = None,
        parsers: SceneParser | None = None,
    ) -> None:
        self._descriptors = {
            d.name: DescriptorInfo(d.name, d.dimension, d.version, d.description)
            for d in REGISTRY.values()
        }
        self.time_limit = time_limit
        self.max_values = max_values
        self.parsers = parsers

    @classmethod
    def from_settings(
        cls, settings: Settings, *, parsers: SceneParser | None = None
    ) -> MotionDescriber:
        """The describer the service uses: MOCAP_DESCRIBE_TIMEOUT_SECONDS and
        MOCAP_MAX_FRAME_VALUES applied; FBX/glTF read by ``parsers``."""
        return cls(
            time_limit=settings.describe_timeout_seconds,
            max_values=settings.max_frame_values,
            parsers=parsers,
        )

    def read(self, upload: Upload, limits: ParseLimits) -> ReadMotion:
        """:func:`read_motion` under this describer's value cap and parser pool."""
        return read_motion(upload, self._capped(limits), self.parsers)

    def _capped(self, limits: ParseLimits) -> ParseLimits:
        if self.max_values is None:
            return limits
        if limits.max_values is not None and limits.max_values <= self.max_values:
            return limits
        return dataclasses.replace(limits, max_values=self.max_values)

    def _check_time(self, started: float, stage: str) -> None:
        if self.time_limit is None:
            return
        elapsed = time.monotonic() - started
        if elapsed > self.time_limit:
            raise DescribeTimeout(
                f"describing the clip took longer than the {self.time_limit:g}-second limit "
                f"(MOCAP_DESCRIBE_TIMEOUT_SECONDS; {elapsed:.1f} s after {stage}); the server "
                "is busy or the clip too long: try again later or upload a shorter clip"
            )

    @property
    def descriptors(self) -> Mapping[str, DescriptorInfo]:
        return self._descriptors

    def describe(
        self, upload: Upload, limits: ParseLimits, *, only: Sequence[str] | None = None
    ) -> Description:
        started = time.monotonic()
        read = self.read(upload, limits)
        self._check_time(started, "reading the file")
        try:
            analysis = analyse(read.motion, descriptors=None if only is None else list(only))
        except ParseError as error:  # e.g. SkeletonMappingError: joints the descriptors need
            raise _name_source(error, upload) from None
        self._check_time(started, "computing the descriptors")
        return Description(
            frame_count=analysis.frame_count,
            frame_time=analysis.frame_time,
            duration=analysis.duration,
            joint_count=analysis.joint_count,
            skeleton_family=analysis.skeleton_family,
            lead_in_frames=analysis.lead_in_frames,
            vectors=check_vectors(analysis.descriptors, self._descriptors),
            animation=read.animation,
            animations=read.animations,
            warnings=analysis.warnings,
            joint_mapping=analysis.joint_mapping,
        )
