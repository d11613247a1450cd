"""Reading, changing and deleting stored clips."""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from pathlib import PurePosixPath

from sqlalchemy.exc import SQLAlchemyError

from app.db import repository as repo
from app.errors import InvalidInput, NotFound, StorageUnavailable
from app.services.library import Library
from app.services.uploads import BVH


@dataclass(frozen=True)
class Download:
    filename: str
    media_type: str
    data: bytes


def get_clip(library: Library, clip_id: int) -> repo.ClipRecord:
    with library.reads() as session:
        clip = repo.get_clip(session, clip_id)
    if clip is None:
        raise NotFound(f"no clip with id {clip_id}")
    return clip


def list_clips(
    library: Library, *, label: str | None, limit: int, offset: int
) -> tuple[list[repo.ClipRecord], int]:
    """One page of clips in id order and the total matching ``label``."""
    with library.reads() as session:
        return repo.list_clips(session, label=label, limit=limit, offset=offset)


def clip_vectors(library: Library, clip_id: int) -> dict[str, repo.StoredVector]:
    """Every stored descriptor vector of the clip, by name."""
    with library.reads() as session:
        return repo.get_vectors(session, clip_id)


def update_clip(
    library: Library, clip_id: int, *, name: str | None, labels: tuple[str, ...] | None
) -> repo.ClipRecord:
    """Rename and/or relabel a clip (``None`` leaves a field as it is)."""
    try:
        with library.writes.begin() as session:
            found = repo.update_clip(session, clip_id, name=name, labels=labels)
    except SQLAlchemyError as exc:
        raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
    if not found:
        raise NotFound(f"no clip with id {clip_id}")
    return get_clip(library, clip_id)


def delete_clip(library: Library, clip_id: int) -> None:
    """Delete the row (vectors and labels go with it), then its vectors from every index, then
    the stored files no other clip uses."""
    with library.write_lock:
        try:
            with library.writes.begin() as session:
                shas = repo.delete_clip(session, clip_id)
        except SQLAlchemyError as exc:
            raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
        if shas is None:
            raise NotFound(f"no clip with id {clip_id}")
        library.indexes.remove([clip_id])
        with library.reads() as session:
            still_used = repo.referenced_blobs(session, shas)
        for sha in set(shas) - still_used:
            library.blobs.delete(sha)


def clip_download(library: Library, clip: repo.ClipRecord, part: str | None) -> Download:
    """The original upload: the BVH file itself, or for ASF/AMC a ZIP of both files — or one
    ``part`` (``"file"``, ``"skeleton"``, ``"motion"``) byte for byte."""
    roles = {f.role: f for f in clip.files}
    if part is not None:
        if part not in roles:
            raise InvalidInput(f"part: clip {clip.id} has the parts {', '.join(roles)}")
        record = roles[part]
        return Download(
            record.filename, "application/octet-stream", library.blobs.read(record.sha256)
        )
    if clip.format == BVH or len(clip.files) == 1:
        record = clip.files[0]
        return Download(
            record.filename, "application/octet-stream", library.blobs.read(record.sha256)
        )
    buffer = io.BytesIO()
    stamp = clip.created_at.timetuple()[:6]
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for record in clip.files:
            info = zipfile.ZipInfo(record.filename, date_time=stamp)
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, library.blobs.read(record.sha256))
    motion = roles.get("motion", clip.files[-1])
    return Download(
        f"{PurePosixPath(motion.filename).stem}.zip", "application/zip", buffer.getvalue()
    )
