"""Finding motion clips in folders.

Shared by the evaluation command and the bulk import. :func:`discover` walks the given paths
and returns every clip it can read as a :class:`ClipSource`:

* every ``.bvh`` file (extension compared case-insensitively) is one clip;
* every ``.amc`` file is one clip paired with an ``.asf`` skeleton **in its own folder**: the
  one whose stem is the AMC's subject prefix (the part of the stem before the first ``_``,
  so ``02_01.amc`` -> ``02.asf``; stems compared case-insensitively), or else the only
  ``.asf`` of that folder. An AMC with no such skeleton is a :class:`DiscoveryFailure`.

Folders are walked recursively; hidden files and folders (names starting with ``.``, e.g.
an ``.eval-cache``) are skipped, symbolic links to folders are not followed. A path given
directly may also be a ``.bvh`` or ``.amc`` file. The result is sorted (by the given path's
position, then the relative path), and a file reached through two given paths is listed once.

:func:`content_hash` is the single definition of a clip's content hash, used by the service
too: the SHA-256 of the file for a BVH, and for an ASF/AMC pair the SHA-256 of the two
files' SHA-256 hex digests concatenated (skeleton first).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

ClipKind = Literal["bvh", "asf/amc", "fbx", "gltf"]

BVH_SUFFIX = ".bvh"
AMC_SUFFIX = ".amc"
ASF_SUFFIX = ".asf"
# Files that may hold several animations (each its own clip), found with ``scenes=True``.
SCENE_SUFFIXES = {
    ".fbx": "fbx",
    ".glb": "gltf",
    ".gltf": "gltf",
    ".vrma": "gltf",
    ".vrm": "gltf",
}


@dataclass(frozen=True)
class ClipSource:
    """One clip found on disk.

    Attributes
    ----------
    kind:
        ``"bvh"`` (one file), ``"asf/amc"`` (a skeleton plus a motion), ``"fbx"`` or
        ``"gltf"`` (one file of one or more animations).
    motion:
        The ``.bvh``, ``.amc``, ``.fbx``, ``.glb``, ``.gltf``, ``.vrma`` or ``.vrm`` file.
    skeleton:
        The ``.asf`` file for ``"asf/amc"``, else ``None``.
    name:
        Display name: the motion file's stem (``02_01``).
    relative_path:
        The motion file's path relative to the folder it was found under, with ``/``
        separators (just the file name for a file given directly).
    root:
        The folder (or file) given to :func:`discover` that led to this clip.
    """

    kind: ClipKind
    motion: Path
    skeleton: Path | None
    name: str
    relative_path: str
    root: Path

    @property
    def paths(self) -> tuple[Path, ...]:
        """``(bvh,)`` or ``(asf, amc)``."""
        return (self.motion,) if self.skeleton is None else (self.skeleton, self.motion)


@dataclass(frozen=True)
class DiscoveryFailure:
    """A file that looks like a clip but cannot be read as one (e.g. an orphan ``.amc``)."""

    path: Path
    reason: str


@dataclass(frozen=True)
class DiscoveryResult:
    sources: list[ClipSource] = field(default_factory=list)
    failures: list[DiscoveryFailure] = field(default_factory=list)


def _suffix(path: Path) -> str:
    return path.suffix.lower()


def _subject_prefix(stem: str) -> str:
    return stem.split("_", 1)[0]


def _pair_skeleton(amc: Path, asf_files: Sequence[Path]) -> Path | str:
    """The skeleton for ``amc`` among the ``.asf`` files of its folder, or why there is none."""
    prefix = _subject_prefix(amc.stem).lower()
    named = [asf for asf in asf_files if asf.stem.lower() == prefix]
    if len(named) == 1:
        return named[0]
    if len(named) > 1:  # e.g. 02.asf and 02.ASF on a case-sensitive file system
        listed = ", ".join(asf.name for asf in named)
        return f"several skeletons match the subject prefix {prefix!r}: {listed}"
    if len(asf_files) == 1:
        return asf_files[0]
    if not asf_files:
        return "no .asf skeleton in its folder"
    listed = ", ".join(sorted(asf.name for asf in asf_files))
    return (
        f"{len(asf_files)} .asf skeletons in its folder ({listed}) and none is named "
        f"{_subject_prefix(amc.stem)}.asf"
    )


def _folder_clips(
    folder: Path, files: Sequence[Path], root: Path, scenes: bool = False
) -> tuple[list[ClipSource], list[DiscoveryFailure]]:
    sources: list[ClipSource] = []
    failures: list[DiscoveryFailure] = []
    asf_files = sorted(f for f in files if _suffix(f) == ASF_SUFFIX)
    for file in sorted(files):
        suffix = _suffix(file)
        scene = SCENE_SUFFIXES.get(suffix) if scenes else None
        if suffix not in (BVH_SUFFIX, AMC_SUFFIX) and scene is None:
            continue
        relative = file.relative_to(root).as_posix() if file != root else file.name
        if scene is not None:
            sources.append(ClipSource(scene, file, None, file.stem, relative, root))  # type: ignore[arg-type]
        elif suffix == BVH_SUFFIX:
            sources.append(ClipSource("bvh", file, None, file.stem, relative, root))
        elif suffix == AMC_SUFFIX:
            skeleton = _pair_skeleton(file, asf_files)
            if isinstance(skeleton, str):
                failures.append(DiscoveryFailure(file, skeleton))
            else:
                sources.append(ClipSource("asf/amc", file, skeleton, file.stem, relative, root))
    return sources, failures


def _visible(name: str) -> bool:
    return not name.startswith(".")


def _walk(root: Path, scenes: bool) -> tuple[list[ClipSource], list[DiscoveryFailure]]:
    sources: list[ClipSource] = []
    failures: list[DiscoveryFailure] = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if _visible(d))
        folder = Path(dirpath)
        files = [folder / name for name in filenames if _visible(name)]
        found, failed = _folder_clips(folder, [f for f in files if f.is_file()], root, scenes)
        sources.extend(found)
        failures.extend(failed)
    return sources, failures


def discover(paths: Sequence[Path], *, scenes: bool = False) -> DiscoveryResult:
    """Every clip under ``paths`` (folders, walked recursively, or ``.bvh``/``.amc`` files;
    with ``scenes`` also ``.fbx``/``.glb``/``.gltf``/``.vrma``/``.vrm`` files).

    A path that does not exist or a file of another kind is reported as a failure.
    """
    sources: list[ClipSource] = []
    failures: list[DiscoveryFailure] = []
    seen: set[Path] = set()
    for given in paths:
        root = Path(given)
        if root.is_dir():
            found, failed = _walk(root, scenes)
            found.sort(key=lambda s: s.relative_path)
        elif root.is_file():
            readable = [BVH_SUFFIX, AMC_SUFFIX, *(SCENE_SUFFIXES if scenes else ())]
            if _suffix(root) not in readable:
                failures.append(DiscoveryFailure(root, f"not a {' or '.join(readable)} file"))
                continue
            siblings = [f for f in root.parent.iterdir() if f.is_file() and _visible(f.name)]
            asf_files = [f for f in siblings if _suffix(f) == ASF_SUFFIX]
            found, failed = _folder_clips(root.parent, [root, *asf_files], root, scenes)
        else:
            failures.append(DiscoveryFailure(root, "no such file or folder"))
            continue
        for source in found:
            key = source.motion.resolve()
            if key not in seen:
                seen.add(key)
                sources.append(source)
        failures.extend(failed)
    failures.sort(key=lambda f: str(f.path))
    return DiscoveryResult(sources, failures)


def file_digest(path: Path) -> str:
    """SHA-256 hex of the file at ``path``, read a megabyte at a time."""
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        for chunk in iter(lambda: stream.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def content_hash_of_bytes(motion: bytes, skeleton: bytes | None = None) -> str:
    """:func:`content_hash` of file contents already in memory (e.g. an upload)."""
    return content_hash_of_digests(
        hashlib.sha256(motion).hexdigest(),
        None if skeleton is None else hashlib.sha256(skeleton).hexdigest(),
    )


def content_hash_of_digests(motion: str, skeleton: str | None = None) -> str:
    """:func:`content_hash` from the files' sha256 hex digests (hashed once, used thrice:
    content hash, stored file name, file-changed check)."""
    if skeleton is None:
        return motion
    return hashlib.sha256((skeleton + motion).encode("ascii")).hexdigest()


def content_hash_of_animation(data: bytes, animation: str, *, digest: str | None = None) -> str:
    """The content hash of one animation of an FBX/glTF file: each animation is its own clip,
    and the same file uploaded or imported again hashes the same. ``digest``: the file's
    sha256 hex digest when already known."""
    digest = digest or hashlib.sha256(data).hexdigest()
    return hashlib.sha256(f"{digest}\n{animation}".encode()).hexdigest()


def content_hash(source: ClipSource) -> str:
    """SHA-256 hex of a BVH's bytes; for ASF/AMC, of ``sha256(asf) + sha256(amc)`` hex digests."""
    if source.skeleton is None:
        return file_digest(source.motion)
    pair = file_digest(source.skeleton) + file_digest(source.motion)
    return hashlib.sha256(pair.encode("ascii")).hexdigest()
