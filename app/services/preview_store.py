"""Stored previews on disk: the figure a clip page draws, one ``.npz`` per clip content and
preview version under ``<data dir>/previews/`` (a cache of what the clips' files give)."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import threading
import zipfile
from pathlib import Path

import numpy as np

from app.config import Settings
from app.motion.display import DisplayMotion
from app.motion.skeleton_map import CANONICAL_JOINTS

log = logging.getLogger(__name__)

PREVIEWS_DIR = "previews"
"""Stored previews, under the data directory (a cache)."""


class PreviewStore:
    """Stored previews on disk, one ``.npz`` per clip content and preview version.

    A cache of what the clips' files give: a file that is missing, unreadable or cannot be
    written costs a parse, never an error.
    """

    def __init__(self, root: Path) -> None:
        self.root = root

    def path(self, content_hash: str, version: str) -> Path:
        return self.root / content_hash[:2] / f"{content_hash}.{version}.npz"

    def load(self, content_hash: str, version: str) -> DisplayMotion | None:
        path = self.path(content_hash, version)
        try:
            with np.load(path, allow_pickle=False) as stored:
                positions = np.asarray(stored["positions"])
                frame_time, source_frame_time, lead_in, source_frames = stored["meta"].tolist()
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
            log.warning("stored preview %s unreadable (%s); reading the clip again", path, error)
            return None
        if positions.ndim != 3 or positions.shape[1:] != (len(CANONICAL_JOINTS), 3):
            return None
        return DisplayMotion(
            positions, float(frame_time), int(lead_in), int(source_frames), float(source_frame_time)
        )

    def save(self, content_hash: str, version: str, display: DisplayMotion) -> None:
        path = self.path(content_hash, version)
        meta = [
            display.frame_time,
            display.source_frame_time,
            display.lead_in_frames,
            display.source_frame_count,
        ]
        buffer = io.BytesIO()
        np.savez(buffer, positions=display.positions, meta=np.asarray(meta, dtype=np.float64))
        temporary = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            temporary.write_bytes(buffer.getvalue())
            os.replace(temporary, path)  # readers see the whole file or none
        except OSError as error:
            log.warning(
                "cannot store the preview %s (%s); it is computed again next time", path, error
            )
            with contextlib.suppress(OSError):  # e.g. no folder to hold it: nothing to remove
                temporary.unlink(missing_ok=True)

    def remove(self, content_hashes: list[str]) -> None:
        """Forget the previews of clips deleted (every version): a deleted clip's motion
        does not stay on disk. Raises OSError when a file cannot be removed."""
        for content_hash in content_hashes:
            for path in (self.root / content_hash[:2]).glob(f"{content_hash}.*.npz"):
                path.unlink(missing_ok=True)

    def stored_hashes(self) -> set[str]:
        """The contents with a stored preview (any version)."""
        if not self.root.is_dir():
            return set()
        return {path.name.split(".", 1)[0] for path in self.root.glob("*/*.npz")}


def preview_store(settings: Settings) -> PreviewStore:
    """The library's stored previews: ``<data dir>/previews/``."""
    return PreviewStore(settings.data_dir / PREVIEWS_DIR)
