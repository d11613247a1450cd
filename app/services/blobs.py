"""Uploaded files, kept content-addressed: ``<root>/<sha256[:2]>/<sha256>``.

Identical bytes are stored once (a CMU skeleton shared by many motions, say); the database's
``clip_files`` rows say which clips use a file, and the service deletes a file only when no
clip refers to it any more.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import threading
from pathlib import Path

from app.errors import StorageUnavailable


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
