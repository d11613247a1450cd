"""Uploaded files, kept content-addressed: ``<root>/<sha256[:2]>/<sha256>``.

Identical bytes are stored once (a CMU skeleton shared by many motions, say); the database's
``clip_files`` rows say which clips use a file, and the service deletes a file only when no
clip refers to it any more.

Paths come from sha256 hex digests only (:meth:`BlobStore.path` refuses anything else): a
file name a user uploads is kept in the database as text and never becomes a path.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import threading
from collections.abc import Iterator
from pathlib import Path

from app.errors import StorageUnavailable

_SHA256 = re.compile(r"[0-9a-f]{64}")


class BlobStore:
    def __init__(self, root: Path) -> None:
        self.root = root

    def path(self, sha256: str) -> Path:
        if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
            raise ValueError(f"not a sha256 hex digest: {sha256!r}")
        return self.root / sha256[:2] / sha256

    def put(self, data: bytes) -> tuple[str, bool]:
        """Store ``data``; returns its sha256 and whether a new file was written."""
        sha = hashlib.sha256(data).hexdigest()
        path = self.path(sha)
        if path.is_file():
            return sha, False
        tmp = path.with_name(f".{sha}.{os.getpid()}.{threading.get_ident()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)  # readers never see a half-written file
        except OSError as exc:
            raise StorageUnavailable(f"cannot store the uploaded file: {exc.strerror}") from exc
        finally:
            # Not there any more once renamed; cleaning up must not hide the real error.
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
        return sha, True

    def read(self, sha256: str) -> bytes:
        try:
            return self.path(sha256).read_bytes()
        except OSError as exc:
            raise StorageUnavailable(
                f"stored file {sha256[:12]}... cannot be read: {exc.strerror}"
            ) from exc

    def exists(self, sha256: str) -> bool:
        return self.path(sha256).is_file()

    def delete(self, sha256: str) -> None:
        path = self.path(sha256)
        path.unlink(missing_ok=True)
        with contextlib.suppress(OSError):  # removes the fan-out directory only when empty
            path.parent.rmdir()

    def stored(self) -> Iterator[tuple[str, Path]]:
        """Every stored file as ``(sha256, path)``; temporary and foreign files are skipped."""
        if not self.root.is_dir():
            return
        for fan_out in sorted(self.root.iterdir()):
            if not fan_out.is_dir() or len(fan_out.name) != 2:
                continue
            for path in sorted(fan_out.iterdir()):
                if _SHA256.fullmatch(path.name) and path.name[:2] == fan_out.name:
                    yield path.name, path

    def temporary_files(self) -> Iterator[Path]:
        """Half-written files a crash left behind (``<fan-out>/.<sha256>.<pid>.<thread>.tmp``)."""
        if self.root.is_dir():
            yield from self.root.glob("??/.*.tmp")

    def sweep(
        self, listed: list[tuple[str, Path]], referenced: set[str], *, older_than: float
    ) -> int:
        """Delete the ``listed`` files (from :meth:`stored`) not in ``referenced``, and the
        temporary files, both only when last modified before ``older_than`` (a ``time.time()``
        value); returns how many went."""
        removed = 0
        candidates = [path for sha, path in listed if sha not in referenced]
        for path in [*candidates, *self.temporary_files()]:
            try:
                if path.stat().st_mtime >= older_than:
                    continue
                path.unlink()
            except FileNotFoundError:
                continue
            removed += 1
            with contextlib.suppress(OSError):
                path.parent.rmdir()
        return removed
