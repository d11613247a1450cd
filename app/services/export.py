"""Downloads ready for an engine: a clip as BVH, FBX or GLB, on a rig, with root motion handled.

One pipeline for ``GET /clips/{id}/file`` and ``POST /exports`` (:func:`export_clip`):

1. the clip's motion, read again from its stored files, cut to ``start``/``end``;
2. ``rig``: retargeted onto a stored rig (:mod:`app.motion.retarget`);
3. ``root``: ``keep``, ``in-place`` or ``extract`` (:mod:`app.motion.root_motion`);
4. ``fps``: resampled (:mod:`app.motion.resampling`);
5. ``units`` (BVH, FBX): lengths converted; the default is the skeleton's own unit for BVH
   and ASF skeletons, centimetres for FBX and glTF ones (read in metres). GLB is metres;
6. written: BVH here; GLB here (+Y up, as glTF says); FBX in an export worker with
   Blender's exporter (+Y up).

``format=bvh`` with every other option at its default is, for BVH and ASF/AMC clips, exactly
the BVH export the service has always given (:func:`~app.motion.formats.bvh_writer.write_bvh`
of the clip as read); FBX and glTF clips, read in metres, now come in centimetres.

The size of an export is bounded before anything is computed: frames x joints of the output
(``fps`` may multiply the frames) count against MOCAP_MAX_FRAME_VALUES like an upload's.
"""

from __future__ import annotations

import csv
import io
import re
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import PurePosixPath

import numpy as np

from app.db import clips as clip_db
from app.errors import InvalidInput, LimitExceeded, MocapError, NoStoredFile
from app.motion.body import body_height
from app.motion.formats.bvh_writer import write_bvh
from app.motion.formats.gltf_writer import write_glb
from app.motion.ground import map_clip
from app.motion.model import Motion
from app.motion.resampling import MAX_FPS, MIN_FPS, resample_to_rate, sample_times
from app.motion.retarget import axis_change, retarget
from app.motion.root_motion import extract_root, in_place, vertical
from app.motion.transforms import rescale, rotate
from app.motion.units import METRIC_FORMATS, UNITS, metres_per_unit
from app.services.describe import read_motion, span_frames
from app.services.library import Library
from app.services.rigs import LoadedRig, get_rig, load_rig

FORMATS = ("bvh", "fbx", "glb")
ROOTS = ("keep", "in-place", "extract")
MEDIA_TYPES = {
    "bvh": "application/octet-stream",
    "fbx": "application/octet-stream",
    "glb": "model/gltf-binary",
}
Y_UP = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class ExportOptions:
    """What a download asks for (names as in the API)."""

    format: str = "bvh"
    units: str | None = None
    fps: float | None = None
    root: str = "keep"
    rig: int | None = None

    def check(self) -> ExportOptions:
        """Itself, or InvalidInput naming the option that is wrong."""
        if self.format not in FORMATS:
            raise InvalidInput(f"format: use one of {', '.join(FORMATS)}, not {self.format!r}")
        if self.units is not None:
            if self.units not in UNITS:
                raise InvalidInput(f"units: use one of {', '.join(UNITS)}, not {self.units!r}")
            if self.format == "glb":
                raise InvalidInput("units: GLB is always in metres (glTF's unit); leave it out")
        if self.fps is not None and not (np.isfinite(self.fps) and MIN_FPS <= self.fps <= MAX_FPS):
            raise InvalidInput(
                f"fps: must be between {MIN_FPS:g} and {MAX_FPS:g} frames per second, "
                f"got {self.fps:g}"
            )
        if self.root not in ROOTS:
            raise InvalidInput(f"root: use one of {', '.join(ROOTS)}, not {self.root!r}")
        return self

    @property
    def is_plain_bvh(self) -> bool:
        """Today's BVH export: nothing but the format asked for."""
        return (
            self.format == "bvh"
            and self.units is None
            and self.fps is None
            and self.root == "keep"
            and self.rig is None
        )

    def describe(self) -> str:
        """The options as query parameters (for the manifest)."""
        words = [f"format={self.format}", f"root={self.root}"]
        if self.rig is not None:
            words.append(f"rig={self.rig}")
        if self.units is not None:
            words.append(f"units={self.units}")
        if self.fps is not None:
            words.append(f"fps={self.fps:g}")
        return " ".join(words)


@dataclass(frozen=True)
class Exported:
    """One written file and what it holds."""

    filename: str
    media_type: str
    data: bytes
    frame_count: int
    frame_time: float
    joint_count: int


@dataclass
class Exporter:
    """Exports of one request: the rig loaded once for every clip."""

    library: Library
    options: ExportOptions
    rig: LoadedRig | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.options.check()
        if self.options.rig is not None:
            self.rig = load_rig(get_rig(self.library, self.options.rig, field="rig"))

    def export(self, clip: clip_db.ClipRecord, frames: tuple[int, int] | None = None) -> Exported:
        """``clip`` (frames ``[start, stop)`` of it) as the options say."""
        if not clip.files:
            raise NoStoredFile(clip.id, clip.format)
        from app.services.clips import stored_upload

        settings = self.library.settings
        if not self.options.is_plain_bvh:  # refused before the file is even read
            count = clip.frame_count if frames is None else max(0, frames[1] - frames[0])
            joints = clip.joint_count if self.rig is None else self.rig.motion.skeleton.joint_count
            _check_size(count, clip.frame_time, joints, self.options, settings.max_frame_values)
        upload = stored_upload(self.library, clip)
        motion = read_motion(upload, settings.parse_limits, self.library.parsers).motion
        if frames is not None:
            motion = motion.slice_frames(max(0, frames[0]), max(0, frames[1]))
        if motion.frame_count == 0:
            raise InvalidInput("start/end: the span holds no frame")
        out = export_motion(
            motion,
            self.options,
            rig=self.rig,
            max_values=settings.max_frame_values,
            fbx=self._write_fbx,
        )
        stem = PurePosixPath(upload.parts[-1].filename).stem or f"clip-{clip.id}"
        if clip.animation is not None and len(clip.animations or ()) > 1:
            stem = f"{stem} - {clip.animation}"
        name = f"{stem}.{self.options.format}"
        if frames is not None:
            start, stop = frames
            name = f"{stem}_{start * clip.frame_time:.2f}-{stop * clip.frame_time:.2f}s"
            name += f".{self.options.format}"
        return Exported(
            name,
            MEDIA_TYPES[self.options.format],
            out.data,
            out.frame_count,
            out.frame_time,
            out.joint_count,
        )

    def _write_fbx(self, motion: Motion, metres: float) -> bytes:
        if self.library.exporters is None:
            from app.errors import FbxUnavailable

            raise FbxUnavailable("format=fbx: no FBX export workers in this process")
        return self.library.exporters.write_fbx(motion, metres_per_unit=metres, name="motion")


@dataclass(frozen=True)
class _Written:
    data: bytes
    frame_count: int
    frame_time: float
    joint_count: int


def _default_metres(source_format: str, metres: float) -> float:
    """The default output unit: the skeleton's own for BVH/ASF, centimetres for FBX/glTF."""
    return UNITS["cm"] if source_format in METRIC_FORMATS else metres


@dataclass(frozen=True, eq=False)
class Prepared:
    """The motion an export writes, before the writer: in ``metres`` metres per unit (the
    output unit for BVH and FBX; GLB converts to metres itself), and the turn from its world
    to +Y up that the GLB and FBX writers apply."""

    motion: Motion
    metres: float
    up_rotation: np.ndarray


def prepare_motion(motion: Motion, options: ExportOptions, rig: LoadedRig | None) -> Prepared:
    """Steps 2-5 of the module docstring on an already read (and cut) motion."""
    source_map = map_clip(motion)
    if rig is not None:
        out = retarget(motion, source_map, rig.motion, rig.mapping)
        mapping = rig.mapping
        metres = rig.record.metres_per_unit
        unit_format = rig.motion.source_format
    else:
        out, mapping = motion, source_map
        height = body_height(motion, mapping.joints, head_joint=mapping.head_joint)
        metres = metres_per_unit(motion.source_format, height)
        unit_format = motion.source_format
    # One vertical for the root's travel and the file's axes: the describer's (a crawl's is
    # its floor's, not its trunk's mean, which lies along the floor).
    up = vertical(out, mapping)
    if options.root == "in-place":
        out = in_place(out, mapping, up)
    elif options.root == "extract":
        out = extract_root(out, mapping, up)
    if options.fps is not None:
        out = resample_to_rate(out, options.fps)
    if options.format != "glb":
        wanted = UNITS[options.units] if options.units else _default_metres(unit_format, metres)
        if abs(wanted - metres) > 1e-12 * wanted:
            out = rescale(out, metres / wanted)
        metres = wanted
    return Prepared(out, metres, axis_change(up, Y_UP))


def export_motion(
    motion: Motion,
    options: ExportOptions,
    *,
    rig: LoadedRig | None,
    max_values: int,
    fbx: object,
) -> _Written:
    """Steps 2-6 of the module docstring on an already read (and cut) motion; ``fbx`` is a
    ``(motion, metres_per_unit) -> bytes`` callable writing FBX files."""
    if options.is_plain_bvh and motion.source_format not in METRIC_FORMATS:
        text = write_bvh(motion)
        return _Written(
            text.encode(), motion.frame_count, motion.frame_time, motion.skeleton.joint_count
        )
    joints = (rig.motion if rig is not None else motion).skeleton.joint_count
    _check_size(motion.frame_count, motion.frame_time, joints, options, max_values)
    prepared = prepare_motion(motion, options, rig)
    out = prepared.motion
    if options.format == "glb":
        data = write_glb(out, metres_per_unit=prepared.metres, up_rotation=prepared.up_rotation)
    elif options.format == "bvh":
        data = write_bvh(out).encode()
    else:
        writer = fbx
        assert callable(writer)
        data = writer(rotate(out, prepared.up_rotation), prepared.metres)
    return _Written(data, out.frame_count, out.frame_time, out.skeleton.joint_count)


def _check_size(
    frames: int, frame_time: float, joints: int, options: ExportOptions, limit: int
) -> None:
    """LimitExceeded before the work when the output would be over MOCAP_MAX_FRAME_VALUES:
    its frames (``fps`` may multiply them) times its joints (one more for ``extract``)."""
    if options.fps is not None:
        frames = len(sample_times(frames, frame_time, options.fps))
    joints += 1
    values = frames * joints * 9
    if values > limit:
        what = f"fps={options.fps:g} makes {frames} frames" if options.fps else f"{frames} frames"
        raise LimitExceeded(
            f"fps: {what} of {joints} joints, {values} values, more than the limit of {limit} "
            "(MOCAP_MAX_FRAME_VALUES); ask for a lower fps or a shorter span"
        )


# -- many clips at once -------------------------------------------------------------------

MANIFEST_COLUMNS = (
    "id",
    "name",
    "file",
    "source",
    "licence",
    "frames",
    "fps",
    "duration",
    "options",
    "error",
)


@dataclass(frozen=True)
class ExportItem:
    """One clip of a ZIP export, optionally a span of it (seconds)."""

    clip: clip_db.ClipRecord
    start: float | None = None
    end: float | None = None


def export_items(
    library: Library,
    *,
    clips: list[tuple[int, float | None, float | None]] | None = None,
    labels: list[str] | None = None,
    search: tuple[int, str | None, int, list[str] | None] | None = None,
) -> list[ExportItem]:
    """The clips of a ZIP export: ``clips`` ``(id, start, end)`` as given; every clip
    carrying all ``labels``; or the hits of a search ``(clip, descriptor, k, label)`` as
    ``GET /search`` finds them. Exactly one of the three; at most MOCAP_MAX_EXPORT_CLIPS."""
    given = [
        name
        for name, value in (("clips", clips), ("label", labels), ("search", search))
        if value is not None
    ]
    if len(given) != 1:
        raise InvalidInput(
            "clips: name the clips to export with exactly one of 'clips', 'label' or 'search'"
            + (f" (got {', '.join(given)})" if given else "")
        )
    limit = library.settings.max_export_clips
    wanted: list[tuple[int, float | None, float | None]]
    if clips is not None:
        wanted = list(clips)
        what = "clips"
    elif labels is not None:
        from app.services.clips import clips_with_labels

        wanted = [
            (clip_id, None, None) for clip_id in clips_with_labels(library, labels, doing="export")
        ]
        what = "label"
    else:
        assert search is not None
        from app.services.search import search_by_clip_id

        clip_id, descriptor, k, label = search
        name = library.default_descriptor if descriptor is None else descriptor
        _, hits = search_by_clip_id(library, clip_id, name, k, label=label)
        wanted = [(hit.clip.id, None, None) for hit in hits]
        what = "search"
    if not wanted:
        raise InvalidInput(f"{what}: no clip to export")
    if len(wanted) > limit:
        raise InvalidInput(
            f"{what}: {len(wanted)} clips, more than the limit of {limit} for one export "
            "(MOCAP_MAX_EXPORT_CLIPS)"
        )
    with library.reads() as session:
        records = clip_db.get_clips(session, {clip_id for clip_id, _, _ in wanted})
    missing = [clip_id for clip_id, _, _ in wanted if clip_id not in records]
    if missing:
        from app.errors import NotFound

        raise NotFound(f"no clip with id {missing[0]}")
    return [ExportItem(records[clip_id], start, end) for clip_id, start, end in wanted]


_UNSAFE = re.compile(r"[\x00-\x1f/\\:*?\"<>|]+")


def _unique(name: str, taken: set[str]) -> str:
    stem, suffix = name.rsplit(".", 1)
    stem = _UNSAFE.sub("_", stem).strip(" .") or "clip"
    candidate, n = f"{stem}.{suffix}", 1
    while candidate.lower() in taken:
        n += 1
        candidate = f"{stem} ({n}).{suffix}"
    taken.add(candidate.lower())
    return candidate


class _Sink(io.RawIOBase):
    """A write-only stream whose bytes are taken out as they come (ZIP streaming)."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []

    def writable(self) -> bool:
        return True

    def write(self, data: object) -> int:
        chunk = bytes(data)  # type: ignore[call-overload]
        self.chunks.append(chunk)
        return len(chunk)

    def take(self) -> bytes:
        out = b"".join(self.chunks)
        self.chunks = []
        return out


def export_each(
    exporter: Exporter, items: Iterable[ExportItem]
) -> Iterator[tuple[ExportItem, Exported | None, str]]:
    """Each item exported in turn: ``(item, exported, "")``, or ``(item, None, reason)`` for
    a clip that cannot be exported (the others go on)."""
    for item in items:
        clip = item.clip
        try:
            frames = None
            if item.start is not None or item.end is not None:
                frames = span_frames(clip.frame_count, clip.frame_time, 0, item.start, item.end)
            yield item, exporter.export(clip, frames), ""
        except MocapError as failure:
            yield item, None, f"{failure.code}: {failure.detail}"


class Manifest:
    """``manifest.csv`` of a many-clip export, and the unique file names in it."""

    def __init__(self, options: ExportOptions) -> None:
        self.options = options
        self.taken: set[str] = {"manifest.csv"}
        self._text = io.StringIO()
        self._rows = csv.writer(self._text, lineterminator="\n")
        self._rows.writerow(MANIFEST_COLUMNS)

    def add(self, item: ExportItem, exported: Exported | None, error: str) -> str | None:
        """Record one clip; the (unique) file name to store its file under, if any."""
        clip = item.clip
        notes = [clip.id, clip.name]
        if exported is None:
            self._rows.writerow(
                [
                    *notes,
                    "",
                    clip.source or "",
                    clip.licence or "",
                    "",
                    "",
                    "",
                    self.options.describe(),
                    error,
                ]
            )
            return None
        filename = _unique(f"{clip.name}.{self.options.format}", self.taken)
        self._rows.writerow(
            [
                *notes,
                filename,
                clip.source or "",
                clip.licence or "",
                exported.frame_count,
                f"{1.0 / exported.frame_time:.6g}",
                f"{exported.frame_count * exported.frame_time:.6g}",
                self.options.describe(),
                "",
            ]
        )
        return filename

    def text(self) -> str:
        return self._text.getvalue()


def export_zip(exporter: Exporter, items: Iterable[ExportItem]) -> Iterator[bytes]:
    """The ZIP of ``items``, streamed: each file as soon as it is written, then
    ``manifest.csv`` (one row per clip; a clip that cannot be exported has its reason in
    ``error`` and no file)."""
    sink = _Sink()
    manifest = Manifest(exporter.options)
    with zipfile.ZipFile(sink, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for item, exported, error in export_each(exporter, items):
            filename = manifest.add(item, exported, error)
            if exported is not None and filename is not None:
                archive.writestr(filename, exported.data)
            yield sink.take()
        archive.writestr("manifest.csv", manifest.text())
    yield sink.take()


__all__ = [
    "FORMATS",
    "ROOTS",
    "ExportItem",
    "ExportOptions",
    "Exported",
    "Exporter",
    "Manifest",
    "export_each",
    "export_items",
    "export_motion",
    "export_zip",
    "prepare_motion",
]
