"""The files of one descriptor's index: ``<name>.faiss``, ``<name>.json`` and (compressed lists)
``<name>.exact.arrays``, in the index directory.

Reading checks the metadata (descriptor, version, dimension, count, the sha256 of the index
file) and maps an IVF file rather than reading it (:mod:`app.index.frozen`: every process
mapping it shares its pages); its checksum may be checked later, off the start-up path
(:meth:`IndexFile.verify`). Writing puts a temporary file in place by renaming it, the exact
vectors of compressed lists first, so an index file never lacks them; the metadata last. The
caller holds the directory's file lock (:func:`app.index.locks.directory_lock`): exclusive
to write, shared to read.
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import time
from pathlib import Path
from typing import Any

import faiss
import numpy as np

from app.index.array_file import (
    file_sha256,
    has_checksum,
    is_stamped,
    read_arrays,
    stream_sha256,
    verify_arrays,
    write_arrays,
    write_stamp,
)
from app.index.frozen import FrozenIVF
from app.index.kinds import (
    FLAT,
    IVF,
    SQ8,
    codes_of,
    has_id_map,
    kind_of,
    padded_width,
    with_id_map,
)
from app.index.locks import directory_lock

log = logging.getLogger(__name__)

EXACT_FORMAT = 1  # the layout of an index's exact vectors file (compressed lists)


def _return_freed_memory() -> None:
    """Give the heap's free pages back to the system (glibc's ``malloc_trim``): mapping an
    index file reads and sorts its ids (the locator) in temporary arrays, whose pages would
    otherwise stay in each server process's resident memory, private to it."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _libc() -> Any:
    try:
        return ctypes.CDLL("libc.so.6")  # glibc; elsewhere nothing is trimmed
    except OSError:
        return None


_LIBC = _libc()


class IndexFile:
    """The files of the index of descriptor ``name`` (of ``dimension`` and ``version``) in
    ``directory``, and what is known of the file mapped last: its inode and metadata, and
    (read with ``verify=False``) the checksums still to check."""

    def __init__(self, name: str, dimension: int, version: int, directory: Path) -> None:
        self.name = name
        self.dimension = dimension
        self.version = version
        self.directory = directory
        self._unchecked: tuple[int, str] | None = None  # see read(verify=False)
        self._unchecked_exact: tuple[Any, Any] | None = None  # ... its exact vectors
        self._mapped_inode = -1  # the index file mapped (see map), and its metadata
        self.mapped_meta: dict[str, Any] = {}

    @property
    def path(self) -> Path:
        return self.directory / f"{self.name}.faiss"

    @property
    def meta_path(self) -> Path:
        return self.directory / f"{self.name}.json"

    def write_temporary(self, index: Any) -> Path:
        """Write the FAISS ``index`` to a temporary file beside the index file (removed again
        when that fails) and return its path, for :meth:`install`."""
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            faiss.write_index(index, str(tmp))
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        return tmp

    def install(
        self,
        tmp: Path,
        meta: dict[str, Any],
        exact: tuple[np.ndarray, np.ndarray] | None,
    ) -> dict[str, Any]:
        """Make the temporary file ``tmp`` the index file (synced to disk first), with its
        exact vectors — sorted ids ``(N,)`` and ``(N, D)`` vectors of compressed lists, written
        before the index file: it never lacks them — and its metadata, ``meta`` plus the
        file's sha256 and the time. Returns the metadata written."""
        compressed = exact is not None
        try:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            meta = {**meta, "sha256": file_sha256(tmp), "saved_at": time.time()}
            if exact is not None:
                write_arrays(
                    self.directory,
                    f"{self.name}.exact",
                    {"ids": exact[0], "vectors": exact[1]},
                    {"format": EXACT_FORMAT, "index_sha256": meta["sha256"]},
                    lock=False,
                )
                del exact
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
        self.write_meta(meta)
        if not compressed:  # float32 lists now: exact vectors of earlier sq8 lists are no use
            for left in self.directory.glob(f"{self.name}.exact.*"):
                left.unlink(missing_ok=True)
        return meta

    def write_meta(self, meta: dict[str, Any]) -> None:
        meta_tmp = self.meta_path.with_name(f".{self.meta_path.name}.{os.getpid()}.tmp")
        try:
            meta_tmp.write_text(json.dumps(meta, indent=2))
            os.replace(meta_tmp, self.meta_path)
        finally:
            meta_tmp.unlink(missing_ok=True)

    def maps(self, meta: dict[str, Any], *, mmap: bool) -> bool:
        """Whether an IVF file of ``meta`` is mapped (compressed lists always are: their
        exact vectors are only read that way)."""
        return mmap or meta.get("codes") == SQ8

    def _read_exact(
        self, meta: dict[str, Any], *, verify: bool
    ) -> tuple[np.ndarray, np.ndarray] | str:
        """The sorted ids ``(N,)`` and ``(N, D)`` exact vectors of the index file of ``meta``
        (mapped), or why they cannot be used: missing, damaged, or written with another index
        file."""
        expect = {"format": EXACT_FORMAT, "index_sha256": meta.get("sha256")}
        found = read_arrays(self.directory, f"{self.name}.exact", expect, verify=verify, lock=False)
        if isinstance(found, str):
            return found
        arrays, exact_meta = found
        ids, vectors = arrays.get("ids"), arrays.get("vectors")
        if vectors is None or vectors.ndim != 2 or vectors.shape[1] != self.dimension:
            return "exact vectors of another shape"
        if ids is None or ids.shape != (vectors.shape[0],) or ids.dtype != np.int64:
            return "exact vectors without their ids"
        if not verify:
            self._unchecked_exact = (arrays, exact_meta)
        return ids, vectors

    def map(self, meta: dict[str, Any], *, verify_exact: bool = True) -> FrozenIVF | None:
        """The index file, mapped (None when it cannot be: the copy in memory stays), with
        its exact vectors when its lists are compressed (the caller holds the directory's
        lock; their checksum is checked later when ``verify_exact`` is False)."""
        try:
            exact: tuple[np.ndarray, np.ndarray] | tuple[None, None] = (None, None)
            if meta.get("codes") == SQ8:
                found = self._read_exact(meta, verify=verify_exact)
                if isinstance(found, str):
                    log.warning("the %s index's exact vectors: %s", self.name, found)
                    return None
                exact = found
            mapped = FrozenIVF.open(str(self.path), exact[1], exact[0])
            self._mapped_inode = os.stat(self.path).st_ino
        except (OSError, RuntimeError) as exc:
            log.warning("could not map the %s index file (%s); holding a copy", self.name, exc)
            return None
        self.mapped_meta = meta
        _return_freed_memory()
        return mapped

    def is_mapped_file(self) -> bool:
        """Whether the index file is still the one mapped (not replaced by another process)."""
        try:
            return os.stat(self.path).st_ino == self._mapped_inode
        except OSError:
            return False

    def read(self, *, verify: bool = True, mmap: bool) -> tuple[Any, dict[str, Any]] | str:
        """The persisted index and its metadata, or why they cannot be used (file work only:
        several indexes can be read at once, in threads). An IVF index is mapped, not read
        (see app/index/frozen.py), when ``mmap`` (:attr:`IndexOptions.mmap`) or its lists are
        compressed; with ``verify=False`` its checksum is checked later, by :meth:`verify`
        (hashing a large file is most of a server's start-up)."""
        with directory_lock(self.directory, exclusive=False):
            try:
                meta = json.loads(self.meta_path.read_text())
                later = not verify and meta.get("kind") == IVF and self.maps(meta, mmap=mmap)
                # Checked now (at once when its stamp shows it unchanged since it matched);
                # "": it does not match.
                expected = meta.get("sha256")
                digest = None if later else expected if has_checksum(self.path, expected) else ""
            except FileNotFoundError as exc:
                return f"missing {Path(exc.filename).name}"
            except (OSError, ValueError) as exc:
                return f"unreadable metadata: {exc}"
            if not isinstance(meta, dict):
                return "unreadable metadata"
            for key, value in (
                ("descriptor", self.name),
                ("version", self.version),
                ("dimension", self.dimension),
            ):
                if meta.get(key) != value:
                    return f"{key} is {meta.get(key)!r}, expected {value!r}"
            if digest is not None and meta.get("sha256") != digest:
                return "index file does not match its checksum"
            try:
                if meta.get("kind") == IVF and self.maps(meta, mmap=mmap):
                    if digest is None:  # the file now mapped, open until checked (the lock
                        # keeps another process from replacing it meanwhile)
                        self._unchecked = (os.open(self.path, os.O_RDONLY), str(meta["sha256"]))
                    mapped = self.map(meta, verify_exact=digest is not None)
                    if mapped is None:
                        return "unreadable index"
                    index: Any = mapped
                    plain: Any = mapped.base
                else:
                    index = plain = faiss.read_index(str(self.path))
            except RuntimeError as exc:
                return f"unreadable index: {exc}"
        width = padded_width(self.dimension) if codes_of(plain) == SQ8 else self.dimension
        if kind_of(plain) is None or plain.d != width:
            return "index of another kind or dimension"
        if kind_of(plain) == IVF and not isinstance(index, FrozenIVF) and not has_id_map(index):
            with_id_map(index)  # a file written before the id map was kept: save it again
            meta["resave"] = True
        if int(index.ntotal) != meta.get("count"):
            return "index count disagrees with its metadata"
        if kind_of(index) == FLAT and index.id_map.size() != index.ntotal:
            return "index count disagrees with its id map"
        return index, meta

    def drop_unchecked(self) -> None:
        self._unchecked_exact = None
        unchecked, self._unchecked = self._unchecked, None
        if unchecked is not None:
            os.close(unchecked[0])

    def verify(self) -> str | None:
        """Check the checksum of the file mapped by ``read(verify=False)``: why it cannot be
        used (the caller rebuilds the index), or None."""
        unchecked, self._unchecked = self._unchecked, None
        exact, self._unchecked_exact = self._unchecked_exact, None
        if exact is not None and (problem := verify_arrays(*exact)) is not None:
            if unchecked is not None:
                os.close(unchecked[0])
            return f"exact vectors: {problem}"
        if unchecked is None:
            return None
        fd, expected = unchecked
        try:
            with os.fdopen(fd, "rb") as stream:
                info = os.fstat(stream.fileno())  # the file mapped, even if replaced since
                if is_stamped(self.path, info, expected):
                    return None  # unchanged since it matched: not hashed again
                digest = stream_sha256(stream)
        except OSError as exc:
            return f"unreadable index file: {exc}"
        if digest != expected:
            return "index file does not match its checksum"
        write_stamp(self.path, info, expected)
        return None
