"""Named numpy arrays in one file, memory-mapped when read: how the in-memory caches beside
the FAISS indexes (the catalogue, the window places) are persisted and shared.

``<stem>.arrays`` holds the arrays one after another (each at a 64-byte boundary);
``<stem>.json`` beside it records where each lies, its dtype and shape, the file's sha256 and
whatever the writer adds (the change-feed position the arrays reflect, a format version).
A file whose checksum was found to match is stamped (``<file>.verified``: its size,
modification time, inode and that checksum, see :func:`has_checksum`), so the next start does
not hash it again while it is unchanged.
Writes go to temporary files renamed into place under the directory's exclusive lock
(:func:`app.index.locks.directory_lock`), so a reader never sees half a file. A read maps the
file read-only: every process reading it shares one copy of its pages (the page cache), and
nothing is copied until a process changes what it holds.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import mmap
import os
import secrets
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from app.index.locks import directory_lock

ALIGN = 64
# Random bytes ending each .arrays file, named by its .json: the two are one write.
TOKEN_BYTES = 16
HASH_CHUNK = 1 << 22
STAMP_SUFFIX = ".verified"  # <file>.verified: the file's checksum was found to match
# Private key read_arrays adds to the metadata it returns (never written to a file): the
# mapped file was known to match its checksum when read, or where to stamp it once checked.
CHECKED = "_checked"


def file_sha256(path: Path) -> str:
    """sha256 of a file, read in chunks (hashlib releases the GIL: files can be checked in
    threads side by side)."""
    with open(path, "rb") as stream:
        return stream_sha256(stream)


def stream_sha256(stream: BinaryIO) -> str:
    """sha256 of what is left to read of ``stream``, read in chunks."""
    digest = hashlib.sha256()
    while chunk := stream.read(HASH_CHUNK):
        digest.update(chunk)
    return digest.hexdigest()


def _stamp_path(path: Path) -> Path:
    return path.with_name(path.name + STAMP_SUFFIX)


def _identity(info: os.stat_result) -> list[int]:
    """What changes when a file is rewritten or replaced: its size, modification time (ns)
    and inode (files here are replaced by a rename, which gives a new inode)."""
    return [info.st_size, info.st_mtime_ns, info.st_ino]


def is_stamped(path: Path, info: os.stat_result, sha256: object) -> bool:
    """Whether ``<path>.verified`` records the file of ``info`` (stat of ``path``) as
    matching ``sha256``."""
    if not isinstance(sha256, str):
        return False
    try:
        stamp = json.loads(_stamp_path(path).read_text())
    except (OSError, ValueError):
        return False
    return (
        isinstance(stamp, dict)
        and stamp.get("file") == _identity(info)
        and stamp.get("sha256") == sha256
    )


def write_stamp(path: Path, info: os.stat_result, sha256: str) -> None:
    """Record that the file of ``info`` (stat of ``path``) matched ``sha256`` (atomically;
    nothing when the directory is read-only: it is hashed again at the next start)."""
    stamp = _stamp_path(path)
    tmp = stamp.with_name(f".{stamp.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        tmp.write_text(json.dumps({"file": _identity(info), "sha256": sha256}))
        os.replace(tmp, stamp)
    except OSError:
        pass
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


def has_checksum(path: Path, sha256: object) -> bool:
    """Whether the file at ``path`` matches ``sha256``: at once when its stamp records this
    very file (unchanged since it was hashed), else hashed — and stamped when it matches, so
    an unchanged file is hashed once, not at every start. A changed file (written again, or
    replaced) has another size, time or inode and is hashed again.

    Raises
    ------
    OSError
        The file cannot be read (``FileNotFoundError``: missing).
    """
    with open(path, "rb") as stream:
        info = os.fstat(stream.fileno())  # of the very file hashed, even if replaced meanwhile
        if not isinstance(sha256, str):
            return False
        if is_stamped(path, info, sha256):
            return True
        digest = stream_sha256(stream)
    if digest != sha256:
        return False
    write_stamp(path, info, sha256)
    return True


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def beside_index(
    index_file: str, suffix: str, identity: list[int], settings: Mapping[str, Any]
) -> tuple[Path, str, dict[str, Any]]:
    """Where arrays derived from the index file ``index_file`` are kept (``<stem>.<suffix>
    .arrays`` beside it) and the stamp they must carry: that very file (``identity``: its
    inode, size and modification time in ns, taken before it was mapped) and the
    ``settings`` they were derived with (a change of either makes them stale)."""
    path = Path(index_file)
    return path.parent, f"{path.stem}.{suffix}", {**settings, "index_file": list(identity)}


def write_arrays(
    directory: Path,
    stem: str,
    arrays: Mapping[str, np.ndarray],
    meta: Mapping[str, Any],
    *,
    lock: bool = True,
) -> None:
    """Write ``arrays`` (C-contiguous copies are taken where needed) and ``meta`` as
    ``<stem>.arrays`` and ``<stem>.json``, atomically, under the directory's lock (``lock=
    False``: the caller holds it)."""
    layout: dict[str, dict[str, Any]] = {}
    with directory_lock(directory, exclusive=True) if lock else contextlib.nullcontext():
        path = directory / f"{stem}.arrays"
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            with open(tmp, "wb") as out:
                offset = 0
                for name, array in arrays.items():
                    data = np.ascontiguousarray(array)
                    pad = -offset % ALIGN
                    out.write(b"\0" * pad)
                    offset += pad
                    layout[name] = {
                        "offset": offset,
                        "dtype": data.dtype.str,
                        "shape": list(data.shape),
                    }
                    out.write(data.data.cast("B"))
                    offset += data.nbytes
                token = secrets.token_bytes(TOKEN_BYTES)
                out.write(token)
            _fsync(tmp)
            described = {
                **meta,
                "arrays": layout,
                "sha256": file_sha256(tmp),
                "token": token.hex(),
            }
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        meta_path = directory / f"{stem}.json"
        meta_tmp = meta_path.with_name(f".{meta_path.name}.{os.getpid()}.tmp")
        try:
            meta_tmp.write_text(json.dumps(described, indent=1))
            os.replace(meta_tmp, meta_path)
        finally:
            meta_tmp.unlink(missing_ok=True)


def read_arrays(
    directory: Path,
    stem: str,
    expect: Mapping[str, Any],
    *,
    verify: bool = True,
    lock: bool = True,
) -> tuple[dict[str, np.ndarray], dict[str, Any]] | str:
    """The arrays of ``<stem>.arrays`` (read-only views of the mapped file) and the metadata,
    or why they cannot be used: a file missing, unreadable or not matching its checksum, or
    metadata differing from ``expect`` (a format version, a descriptor). With
    ``verify=False`` the checksum is left to :func:`verify_arrays` (later, in a thread) unless
    the file's stamp shows it matched already; ``lock=False``: the caller holds the
    directory's lock."""
    path = directory / f"{stem}.arrays"
    with directory_lock(directory, exclusive=False) if lock else contextlib.nullcontext():
        try:
            meta = json.loads((directory / f"{stem}.json").read_text())
            if not isinstance(meta, dict) or not isinstance(meta.get("arrays"), dict):
                return "unreadable metadata"
            for key, value in expect.items():
                if meta.get(key) != value:
                    return f"{key} is {meta.get(key)!r}, expected {value!r}"
            if verify and not has_checksum(path, meta.get("sha256")):
                return f"{path.name} does not match its checksum"
            with open(path, "rb") as stream:
                info = os.fstat(stream.fileno())
                mapped = (
                    mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) if info.st_size else None
                )
            if not _same_write(mapped, meta):
                return f"{path.name} and {stem}.json are from different writes"
            # The file mapped: checked (now, or before when its stamp says so), or where to
            # stamp it once verify_arrays has checked it.
            checked = verify or is_stamped(path, info, meta.get("sha256"))
            meta[CHECKED] = True if checked else [str(path), info]
        except FileNotFoundError as exc:
            return f"missing {Path(exc.filename).name}"
        except (OSError, ValueError) as exc:
            return f"unreadable {stem} file: {exc}"
    arrays = {}
    try:
        for name, where in meta["arrays"].items():
            dtype = np.dtype(where["dtype"])
            shape = tuple(int(n) for n in where["shape"])
            count = int(np.prod(shape, dtype=np.int64))
            if count == 0 or mapped is None:
                arrays[name] = np.zeros(shape, dtype)
                continue
            array = np.frombuffer(mapped, dtype, count, int(where["offset"]))
            arrays[name] = array.reshape(shape)
    except (KeyError, TypeError, ValueError) as exc:
        return f"unreadable {stem} metadata: {exc}"
    return arrays, meta


def _same_write(mapped: mmap.mmap | None, meta: Mapping[str, Any]) -> bool:
    """Whether the mapped ``.arrays`` file ends with the token its metadata names. The two
    files are replaced one after the other: a process killed between the two renames leaves
    the new arrays beside the old metadata (whose layout would read them as garbage), which
    a start that defers the checksum (``verify=False``) must not take. Metadata without a
    token (written before tokens) is taken as before."""
    token = meta.get("token")
    if token is None:
        return True
    if not isinstance(token, str) or mapped is None:
        return False
    try:
        expected = bytes.fromhex(token)
    except ValueError:
        return False
    return len(expected) == TOKEN_BYTES and mapped[-TOKEN_BYTES:] == expected


def verify_arrays(arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> str | None:
    """Check the checksum of arrays read with ``verify=False`` (the mapped file itself, even if
    another process has replaced the file since): why they cannot be used, or None. A file
    its stamp showed unchanged since it matched is not hashed again; one that matches now is
    stamped."""
    checked = meta.get(CHECKED)
    if checked is True:
        return None
    mapped = next(filter(None, (_mapping_of(a) for a in arrays.values())), None)
    if mapped is None:  # an empty file: nothing mapped
        return None
    digest = hashlib.sha256()
    view = memoryview(mapped)
    for start in range(0, len(view), HASH_CHUNK):
        digest.update(view[start : start + HASH_CHUNK])
    view.release()
    if digest.hexdigest() != meta.get("sha256"):
        return "file does not match its checksum"
    if isinstance(checked, list):  # the very file mapped, stamped if it was not replaced
        path, info = Path(checked[0]), checked[1]
        with contextlib.suppress(OSError):
            if _identity(os.stat(path)) == _identity(info):
                write_stamp(path, info, digest.hexdigest())
    return None


def _mapping_of(array: np.ndarray) -> mmap.mmap | None:
    """The file mapping an array of :func:`read_arrays` is a view of, if any."""
    base: Any = array
    while base is not None and not isinstance(base, mmap.mmap):
        base = base.obj if isinstance(base, memoryview) else getattr(base, "base", None)
    return base
