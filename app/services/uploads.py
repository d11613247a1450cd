"""What a user uploads: one BVH, FBX or glTF file, or an ASF skeleton plus an AMC motion.

:class:`Upload` checks which parts were sent and their file types, names the clip by default,
normalises labels, and computes the content hash that identifies the clip:

* BVH: ``sha256(file bytes)``;
* ASF/AMC: ``sha256`` of the two files' hex digests joined (skeleton first), so the hash
  depends on both files and on which is which;
* FBX / glTF: ``sha256`` of the file's hex digest and the animation's name, so each
  animation of a file is its own clip (known once the file is read, see ``animation``).

The rule has one definition, :func:`app.discovery.content_hash_of_digests`, which the bulk
import uses too: a clip uploaded over HTTP and the same files imported from disk are one clip.
"""

from __future__ import annotations

import hashlib
import unicodedata
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import PurePosixPath, PureWindowsPath

from app.discovery import content_hash_of_animation, content_hash_of_digests
from app.errors import InvalidInput, UnsupportedMediaType
from app.labels import normalise_labels
from app.motion.formats.gltf_pack import pack_gltf, refers_to_files
from app.motion.formats.scene_animation import Animation
from app.text import checked_text

MAX_NAME_LENGTH = 255
MAX_SOURCE_LENGTH = 500  # source and licence: the columns' size

BVH = "bvh"
ASF_AMC = "asf/amc"
FBX = "fbx"
GLTF = "gltf"
SCENE_FORMATS = (FBX, GLTF)  # files with several animations, read in parser workers

# The format of a lone 'file' by its extension.
# A VRM model (``.vrm``) is a GLB: read as one, it is a rig (most hold no animation).
FILE_FORMATS = {
    ".bvh": BVH,
    ".fbx": FBX,
    ".glb": GLTF,
    ".gltf": GLTF,
    ".vrma": GLTF,
    ".vrm": GLTF,
}
# Upload field -> the file extensions it takes.
EXTENSIONS = {"file": tuple(FILE_FORMATS), "skeleton": (".asf",), "motion": (".amc",)}
ACCEPTED = (
    "supported: .bvh, .fbx, .glb, .gltf, .vrma or .vrm as 'file' (a .gltf with the files it refers "
    "to as further 'file' fields), or .asf as 'skeleton' with .amc as 'motion'"
)
MAX_ANIMATION_NAME = 255


@dataclass(frozen=True)
class UploadPart:
    """One uploaded file: the form field it came in (``role``), its name and bytes."""

    role: str
    filename: str
    data: bytes = field(repr=False)

    @cached_property
    def sha256(self) -> str:
        return hashlib.sha256(self.data).hexdigest()

    @property
    def size(self) -> int:
        return len(self.data)


def clean_filename(raw: str | None, role: str) -> str:
    """The base name of an uploaded file (clients may send a path), control characters
    replaced by ``_``. Only ever stored as text: stored files are named by content hash."""
    name = PureWindowsPath(PurePosixPath(raw or "").name).name
    # Control characters and lone surrogates (no UTF-8 exists for them) become "_".
    name = "".join("_" if unicodedata.category(c) in ("Cc", "Cs") else c for c in name).strip()
    if not name:
        raise InvalidInput(f"field '{role}': the uploaded file has no file name")
    return name[-MAX_NAME_LENGTH:]


def normalise_animation(value: str | None) -> str | None:
    """The requested animation name (surrounding space kept off); ``None`` when blank."""
    if value is None or not value.strip():
        return None
    if len(value) > MAX_ANIMATION_NAME:
        raise InvalidInput(f"animation: at most {MAX_ANIMATION_NAME} characters")
    return checked_text("animation", value.strip())


def normalise_name(value: str | None) -> str | None:
    """A clip name stripped of surrounding space; ``None`` when absent or blank."""
    if value is None or not value.strip():
        return None
    name = checked_text("name", value.strip())
    if len(name) > MAX_NAME_LENGTH:
        raise InvalidInput(f"name: at most {MAX_NAME_LENGTH} characters")
    return name


def normalise_note(field: str, value: str | None) -> str | None:
    """A source or licence text stripped of surrounding space; ``None`` when absent or blank."""
    if value is None or not value.strip():
        return None
    text = checked_text(field, value.strip())
    if len(text) > MAX_SOURCE_LENGTH:
        raise InvalidInput(f"{field}: at most {MAX_SOURCE_LENGTH} characters")
    return text


@dataclass(frozen=True)
class Upload:
    """A validated upload; build it with :meth:`from_files`."""

    parts: tuple[UploadPart, ...]
    name: str | None = None
    labels: tuple[str, ...] = ()
    source: str | None = None
    licence: str | None = None
    animation: str | None = None  # FBX/glTF: the one to read (None: the longest), once read
    animations: tuple[Animation, ...] = ()  # FBX/glTF: every animation, once read

    @classmethod
    def from_files(
        cls,
        *,
        file: tuple[str | None, bytes] | None = None,
        skeleton: tuple[str | None, bytes] | None = None,
        motion: tuple[str | None, bytes] | None = None,
        name: str | None = None,
        labels: Iterable[str] | None = None,
        source: str | None = None,
        licence: str | None = None,
        animation: str | None = None,
        resources: Mapping[str, bytes] | None = None,
    ) -> Upload:
        """Check which parts were sent and their types.

        Each part is ``(file name, bytes)``. ``resources`` are the files a ``.gltf`` refers
        to, by name (further ``file`` fields, or a bulk import's folder): such a ``.gltf`` is
        stored as the one ``.glb`` of it and them (:func:`pack_gltf`). Raises
        :class:`InvalidInput` for a missing or surplus part (naming the field) and
        :class:`UnsupportedMediaType` for a file whose extension does not fit its field.
        """
        if file is not None and (skeleton is not None or motion is not None):
            extra = "skeleton" if skeleton is not None else "motion"
            raise InvalidInput(
                f"field '{extra}': send either 'file' (one .bvh, .fbx, .glb, .gltf, .vrma or .vrm) "
                "or 'skeleton' (.asf) with 'motion' (.amc), not both"
            )
        if file is not None:
            given = {"file": file}
        elif skeleton is not None and motion is not None:
            given = {"skeleton": skeleton, "motion": motion}
        elif skeleton is not None:
            raise InvalidInput("field 'motion': the .asf skeleton must come with an .amc 'motion'")
        elif motion is not None:
            raise InvalidInput(
                "field 'skeleton': the .amc motion must come with its .asf 'skeleton'"
            )
        else:
            raise InvalidInput(
                "field 'file': no upload; send 'file' (one .bvh, .fbx, .glb, .gltf, .vrma or .vrm) "
                "or 'skeleton' (.asf) with 'motion' (.amc) as multipart/form-data"
            )
        parts = []
        for role, (raw_name, data) in given.items():
            filename = clean_filename(raw_name, role)
            suffix = PurePosixPath(filename).suffix.lower()
            if suffix not in EXTENSIONS[role]:
                expected = " or ".join(EXTENSIONS[role])
                raise UnsupportedMediaType(
                    f"field '{role}': expected a {expected} file, got {filename!r} ({ACCEPTED})"
                )
            if not data:
                raise InvalidInput(f"field '{role}': the file {filename!r} is empty")
            parts.append(UploadPart(role, filename, data))
        parts = _packed(parts, {} if resources is None else resources)
        upload = cls(
            tuple(parts),
            normalise_name(name),
            normalise_labels(labels),
            normalise_note("source", source),
            normalise_note("licence", licence),
        )
        chosen = normalise_animation(animation)
        if chosen is not None and upload.format not in SCENE_FORMATS:
            raise InvalidInput(
                "animation: only FBX and glTF files hold several animations; leave it out for "
                f"a {upload.format.upper()} upload"
            )
        return upload if chosen is None else replace(upload, animation=chosen)

    @property
    def format(self) -> str:
        if len(self.parts) > 1:
            return ASF_AMC
        return FILE_FORMATS.get(PurePosixPath(self.parts[0].filename).suffix.lower(), BVH)

    @property
    def knows_content_hash(self) -> bool:
        """False for an FBX/glTF upload whose animation is not known until it is read."""
        return self.format not in SCENE_FORMATS or self.animation is not None

    def with_animations(self, animations: tuple[Animation, ...], chosen: str) -> Upload:
        """The upload once read: which animation it holds and every one of the file."""
        return replace(self, animation=chosen, animations=animations)

    def part(self, role: str) -> UploadPart:
        for part in self.parts:
            if part.role == role:
                return part
        raise KeyError(role)

    @cached_property
    def content_hash(self) -> str:
        if self.format in SCENE_FORMATS:
            if self.animation is None:
                raise ValueError("the content hash of an FBX/glTF upload needs its animation")
            part = self.parts[0]
            return content_hash_of_animation(part.data, self.animation, digest=part.sha256)
        if self.format == BVH:
            return content_hash_of_digests(self.parts[0].sha256)
        return content_hash_of_digests(self.part("motion").sha256, self.part("skeleton").sha256)

    @property
    def clip_name(self) -> str:
        """The name to store: the given one, else the (motion) file name without extension,
        followed by `` · <animation>`` for a file that holds several animations."""
        if self.name:
            return self.name
        main = self.part("motion") if self.format == ASF_AMC else self.parts[0]
        stem = PurePosixPath(main.filename).stem or main.filename
        if self.animation is not None and len(self.animations) > 1:
            return f"{stem} · {self.animation}"[:MAX_NAME_LENGTH]
        return stem


def split_files(
    sent: list[tuple[str | None, bytes]], suffixes: Iterable[str] = tuple(FILE_FORMATS)
) -> tuple[tuple[str | None, bytes] | None, dict[str, bytes]]:
    """The main file of an upload's repeated ``file`` fields (the one whose extension is in
    ``suffixes``, else the first) and the others by file name: the files a ``.gltf`` refers
    to."""
    if not sent:
        return None, {}
    wanted = tuple(suffixes)
    mains = [f for f in sent if PurePosixPath(f[0] or "").suffix.lower() in wanted]
    main = mains[0] if len(mains) == 1 else sent[0]
    return main, {clean_filename(f[0], "file"): f[1] for f in sent if f is not main}


def packed_file(filename: str, data: bytes, resources: Mapping[str, bytes]) -> tuple[str, bytes]:
    """``(filename, data)`` of an uploaded file: a ``.gltf`` that refers to other files made
    the one ``.glb`` of it and ``resources`` (:func:`pack_gltf`), any other file as it is.
    Files sent with one that refers to none are refused (422), naming them."""
    if PurePosixPath(filename).suffix.lower() != ".gltf" or not refers_to_files(data):
        if resources:
            raise InvalidInput(
                f"field 'file': send one file; more than one only for a .gltf and the files it "
                f"refers to (got also {', '.join(repr(n) for n in list(resources)[:5])})"
            )
        return filename, data
    packed = pack_gltf(data, resources, what=f"field 'file': {filename!r}")
    return (PurePosixPath(filename).stem + ".glb")[-MAX_NAME_LENGTH:], packed


def _packed(parts: list[UploadPart], resources: Mapping[str, bytes]) -> list[UploadPart]:
    """The parts, a ``.gltf`` that refers to other files made one ``.glb`` of them."""
    if len(parts) != 1:
        return parts
    name, data = packed_file(parts[0].filename, parts[0].data, resources)
    return parts if data is parts[0].data else [UploadPart(parts[0].role, name, data)]
