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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NoReturn, Protocol

import numpy as np

from app.errors import DescribeTimeout, InvalidInput, LimitExceeded, ParseError, UnreadableFile
from app.motion.body import Body
from app.motion.descriptors import REGISTRY
from app.motion.display import DisplayMotion, stored_preview_of
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.scene_animation import Animation
from app.motion.model import Motion, ParseLimits
from app.motion.pipeline import analyse, describable_body
from app.motion.windows import (
    DEFAULT_LENGTHS,
    describe_windows,
    slice_body,
    window_frames,
    window_spans,
)
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


# Descriptors whose windows are stored and indexed for moments search, and the window
# lengths (seconds). Each window costs a row and an index entry per descriptor: ``motion``
# only keeps 100 hours of windows within the memory budget (bench/README.md).
WINDOW_DESCRIPTORS: tuple[str, ...] = ("motion",)
WINDOW_LENGTHS: tuple[float, ...] = DEFAULT_LENGTHS


@dataclass(frozen=True)
class Windows:
    """A clip's windows: ``spans`` ``(W, 3)`` int64 ``[length index, start, stop)`` in frames
    of the file as uploaded (lead-in included), ``lengths`` the seconds each length index
    stands for, ``vectors[name]`` ``(W, D)`` float32."""

    lengths: tuple[float, ...]
    spans: np.ndarray
    vectors: dict[str, np.ndarray]


@dataclass(frozen=True)
class SpanDescription:
    """One span of a clip described under one descriptor (a moments query): frames
    ``[start_frame, end_frame)`` of the file, ``vector`` ``(D,)`` float32."""

    frame_count: int
    frame_time: float
    lead_in_frames: int
    start_frame: int
    end_frame: int
    vector: np.ndarray
    # The span's own windows of ``part_length`` seconds: ``part_offsets`` (J,) frames from
    # ``start_frame``, ``parts`` (J, D) float32 (empty when not asked for or too short).
    part_length: float = 0.0
    part_offsets: np.ndarray = dataclasses.field(default_factory=lambda: np.empty(0, np.int64))
    parts: np.ndarray = dataclasses.field(default_factory=lambda: np.empty((0, 0), np.float32))
    animation: str | None = None  # FBX/glTF: the animation read


@dataclass(frozen=True)
class Description:
    """What the motion core measured on one clip; ``vectors[name]`` is ``(D,)`` float32;
    ``windows`` the windows of the descriptors in :data:`WINDOW_DESCRIPTORS` (``None`` when
    not asked for); ``preview`` the clip's stored preview
    (:func:`~app.motion.display.stored_preview_of`: its canonical joints in the display frame
    at 30 fps, float32), made from the body the descriptors were computed from so that storing
    the clip stores it without parsing the file again (``None`` when not asked for)."""

    frame_count: int
    frame_time: float
    duration: float
    joint_count: int
    skeleton_family: str
    lead_in_frames: int
    vectors: dict[str, np.ndarray]
    windows: Windows | None = None
    preview: DisplayMotion | None = None
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
        Seconds one :meth:`describe` may take, or ``None``. It reaches inside the parse: the
        readers get it as ``ParseLimits.deadline`` and look at the clock between bounded
        chunks of their work (every few thousand lines, around each C reader call, per chunk
        of rotations), so a hostile file stops there; then it is checked between the stages
        (kinematics and descriptors, windows), each bounded by the parse limits. Past it:
        :class:`~app.errors.DescribeTimeout` (503), and the thread is free again.
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
        windows: bool = True,
    ) -> None:
        self._descriptors = {
            d.name: DescriptorInfo(d.name, d.dimension, d.version, d.description)
            for d in REGISTRY.values()
        }
        self.time_limit = time_limit
        self.max_values = max_values
        self.parsers = parsers
        # The descriptors described as windows too (none when moments search is off).
        self.window_descriptors = WINDOW_DESCRIPTORS if windows else ()

    @classmethod
    def from_settings(
        cls, settings: Settings, *, parsers: SceneParser | None = None
    ) -> MotionDescriber:
        """The describer the service uses: MOCAP_DESCRIBE_TIMEOUT_SECONDS,
        MOCAP_MAX_FRAME_VALUES and MOCAP_MOMENTS applied; FBX/glTF read by ``parsers``."""
        return cls(
            time_limit=settings.describe_timeout_seconds,
            max_values=settings.max_frame_values,
            parsers=parsers,
            windows=settings.moments,
        )

    def read(
        self, upload: Upload, limits: ParseLimits, *, started: float | None = None
    ) -> ReadMotion:
        """:func:`read_motion` under this describer's value cap and parser pool, and its time
        limit counted from ``started`` (a :func:`time.monotonic` instant; default now)."""
        limits = self._capped(limits)
        begun = time.monotonic() if started is None else started
        if self.time_limit is not None:
            limits = dataclasses.replace(limits, deadline=begun + self.time_limit)
        try:
            return read_motion(upload, limits, self.parsers)
        except DescribeTimeout:
            self._timed_out(begun, "while reading the file")

    def _body(self, motion: Motion, upload: Upload) -> Body:
        """The one verdict (:func:`~app.motion.pipeline.describable_body`), naming the file."""
        try:
            return describable_body(motion)
        except ParseError as error:  # e.g. SkeletonMappingError: joints the descriptors need
            raise _name_source(error, upload) from None

    def _capped(self, limits: ParseLimits) -> ParseLimits:
        if self.max_values is None:
            return limits
        if limits.max_values is not None and limits.max_values <= self.max_values:
            return limits
        return dataclasses.replace(limits, max_values=self.max_values)

    def _check_time(self, started: float, stage: str) -> None:
        if self.time_limit is None:
            return
        if time.monotonic() - started > self.time_limit:
            self._timed_out(started, f"after {stage}")

    def _timed_out(self, started: float, when: str) -> NoReturn:
        elapsed = time.monotonic() - started
        raise DescribeTimeout(
            f"describing the clip took longer than the {self.time_limit:g}-second limit "
            f"(MOCAP_DESCRIBE_TIMEOUT_SECONDS; {elapsed:.1f} s, {when}); the server "
            "is busy or the clip too long: try again later or upload a shorter clip"
        )

    @property
    def descriptors(self) -> Mapping[str, DescriptorInfo]:
        return self._descriptors

    def describe(
        self,
        upload: Upload,
        limits: ParseLimits,
        *,
        only: Sequence[str] | None = None,
        windows: bool | None = None,
        preview: bool | None = None,
    ) -> Description:
        """:meth:`Describer.describe`; with ``windows`` (default: when describing every
        descriptor) also the windows of :attr:`window_descriptors`, with ``preview`` (default:
        the same) the clip's stored preview (:attr:`Description.preview`)."""
        started = time.monotonic()
        read = self.read(upload, limits, started=started)
        self._check_time(started, "reading the file")
        body = self._body(read.motion, upload)
        analysis = analyse(read.motion, descriptors=None if only is None else list(only), body=body)
        self._check_time(started, "computing the descriptors")
        described_windows = None
        if windows is None:
            windows = only is None and bool(self.window_descriptors)
        if windows:
            described_windows = self._windows(analysis.body)
            self._check_time(started, "describing the windows")
        if preview is None:
            preview = only is None
        # A few matrix products on the body at hand, against a parse of the file (0.1-0.7 s)
        # when a page first shows a clip stored without its preview.
        stored_preview = stored_preview_of(analysis.body) if preview else None
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
            windows=described_windows,
            preview=stored_preview,
        )

    def _windows(self, body: Body) -> Windows:
        spans = window_spans(body.frame_count, body.frame_time, WINDOW_LENGTHS)
        names = [name for name in self.window_descriptors if name in self._descriptors]
        vectors = describe_windows(body, spans, names)
        for name, array in vectors.items():
            if not np.all(np.isfinite(array)):
                raise InvalidInput(
                    f"the clip cannot be described: a window's {name!r} vector is not finite "
                    "(degenerate motion)"
                )
        file_spans = spans.copy()
        file_spans[:, 1:] += body.lead_in_frames
        return Windows(WINDOW_LENGTHS, file_spans, vectors)

    def describe_span(
        self,
        upload: Upload,
        limits: ParseLimits,
        name: str,
        start: float | None,
        end: float | None,
        *,
        min_seconds: float = 0.0,
        part_length: Callable[[float], float] | None = None,
        part_step: float = 1 / 30,
        max_parts: int | None = None,
    ) -> SpanDescription:
        """Describe the part ``[start, end)`` (seconds from the file's first frame; ``None``:
        its start / end) of ``upload`` under descriptor ``name``. A span of the whole clip
        gives the clip's vector. With ``part_length`` (span seconds -> window seconds) also
        the span's own windows of that length, one every ``part_step`` seconds (at least a
        frame; more apart when that would make over ``max_parts``) and one ending with the
        span."""
        started = time.monotonic()
        read = self.read(upload, limits, started=started)
        motion = read.motion
        self._check_time(started, "reading the file")
        body = self._body(motion, upload)
        first, stop = span_frames(
            motion.frame_count, motion.frame_time, body.lead_in_frames, start, end, min_seconds
        )
        lead_in = body.lead_in_frames
        part = slice_body(body, first - lead_in, stop - lead_in)
        vector = check_vectors({name: REGISTRY[name].compute(part)}, self._descriptors)[name]
        self._check_time(started, "computing the descriptor")
        description = SpanDescription(
            motion.frame_count,
            motion.frame_time,
            lead_in,
            first,
            stop,
            vector,
            animation=read.animation,
        )
        if part_length is None:
            return description
        length = part_length(part.frame_count * motion.frame_time)
        size = window_frames(length, motion.frame_time)
        if size > part.frame_count:
            return description
        step = max(1, int(np.floor(part_step / motion.frame_time + 0.5)))
        places = part.frame_count - size + 1
        if max_parts is not None and places > max_parts * step:
            step = -(-places // max_parts)
        offsets = np.arange(0, places, step, dtype=np.int64)
        if offsets[-1] + size < part.frame_count:
            offsets = np.append(offsets, part.frame_count - size)
        spans = np.stack([np.zeros_like(offsets), offsets, offsets + size], axis=1)
        parts = describe_windows(part, spans, [name])[name]
        self._check_time(started, "describing the span's windows")
        if not np.all(np.isfinite(parts)):
            return description
        return dataclasses.replace(
            description, part_length=length, part_offsets=offsets, parts=parts
        )


def span_frames(
    frame_count: int,
    frame_time: float,
    lead_in_frames: int,
    start: float | None,
    end: float | None,
    min_seconds: float = 0.0,
) -> tuple[int, int]:
    """Frames ``[first, stop)`` of the file for the span ``[start, end)`` in seconds from its
    first frame (``None``: the clip's start / end). Lead-in frames are never described: a
    span starting in them starts after them.

    Raises :class:`InvalidInput` (422) for ``start >= end``, a span outside the clip, or one
    shorter than ``min_seconds`` (half a frame of slack) that is not the whole clip.
    """
    duration = frame_count * frame_time
    s = 0.0 if start is None else float(start)
    e = duration if end is None else float(end)
    if not (np.isfinite(s) and np.isfinite(e)):
        raise InvalidInput("start, end: must be finite numbers of seconds")
    if s >= e:
        raise InvalidInput(f"start ({s:g} s) must be before end ({e:g} s)")
    slack = frame_time / 2
    if s < -slack or e > duration + slack:
        raise InvalidInput(
            f"the span [{s:g} s, {e:g} s) lies outside the clip, which lasts {duration:g} s "
            f"({frame_count} frames at {1 / frame_time:g} fps)"
        )
    first = max(lead_in_frames, min(frame_count - 1, int(np.floor(s / frame_time + 0.5))))
    stop = min(frame_count, max(first + 1, int(np.floor(e / frame_time + 0.5))))
    whole = first == lead_in_frames and stop == frame_count
    if not whole and (stop - first) * frame_time < min_seconds - slack:
        raise InvalidInput(
            f"the span [{s:g} s, {e:g} s) is shorter than the shortest window "
            f"({min_seconds:g} s); choose a longer span"
        )
    return first, stop
