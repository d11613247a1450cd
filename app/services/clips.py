"""Reading, changing and deleting stored clips."""

from __future__ import annotations

import io
import logging
import time
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import PurePosixPath

import numpy as np
from sqlalchemy.exc import SQLAlchemyError

from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import vectors as vector_db
from app.db.clip_filters import ClipFilter, selected_ids
from app.db.relabel import Relabelled, relabel
from app.errors import InvalidInput, NoStoredFile, NotFound, ParseError, StorageUnavailable
from app.motion.formats import decode_text
from app.motion.formats.bvh_writer import write_bvh
from app.motion.formats.cut import cut_amc, cut_bvh
from app.services.describe import read_motion, span_frames
from app.services.library import Library, drop_clip_windows
from app.services.preview_store import preview_store
from app.services.uploads import ASF_AMC, BVH, Upload

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Download:
    filename: str
    media_type: str
    data: bytes


# Ids are 64-bit signed integers in every database; a larger number names no clip (and would
# overflow the database driver).
MAX_ID = 2**63 - 1


def get_clip(library: Library, clip_id: int) -> clip_db.ClipRecord:
    if not 0 < clip_id <= MAX_ID:
        raise NotFound(f"no clip with id {clip_id}")
    with library.reads() as session:
        clip = clip_db.get_clip(session, clip_id)
    if clip is None:
        raise NotFound(f"no clip with id {clip_id}")
    return clip


def list_clips(
    library: Library,
    *,
    selection: ClipFilter | None = None,
    label: label_db.LabelFilter = None,
    sort: str = "id",
    limit: int,
    offset: int,
) -> tuple[list[clip_db.ClipRecord], int]:
    """One page of the clips ``selection`` (or ``label``) keeps, ordered by ``sort`` (see
    :data:`app.db.clips.SORT_KEYS`), and how many it keeps in all."""
    with library.reads() as session:
        return clip_db.list_clips(
            session, selection=selection, label=label, sort=sort, limit=limit, offset=offset
        )


def relabel_clips(
    library: Library,
    selection: ClipFilter,
    *,
    add: tuple[str, ...],
    remove: tuple[str, ...],
    every: bool = False,
) -> Relabelled:
    """Add and remove labels on every clip ``selection`` keeps (an empty selection only with
    ``every``: then every clip), in one transaction."""
    if not selection and not every:
        raise InvalidInput("name the clips: ids, label, licence or q (all: true for every clip)")
    if not add and not remove:
        raise InvalidInput("add, remove: give a label to add or to remove")
    try:
        with library.writes.begin() as session:
            relabelled = relabel(session, selection, add=add, remove=remove)
    except SQLAlchemyError as exc:
        raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
    if relabelled.changed:
        library.sync_indexes()  # searches here filter by the new labels at once
        library.edits += 1
    return relabelled


def clip_vectors(library: Library, clip_id: int) -> dict[str, vector_db.StoredVector]:
    """Every stored descriptor vector of the clip, by name."""
    with library.reads() as session:
        return vector_db.get_vectors(session, clip_id)


def update_clip(
    library: Library,
    clip_id: int,
    *,
    name: str | None,
    labels: tuple[str, ...] | None,
    notes: Mapping[str, str | None] | None = None,
) -> clip_db.ClipRecord:
    """Rename and/or relabel a clip (``None`` leaves a field as it is); ``notes`` sets
    ``source`` and/or ``licence`` (a ``None`` value clears one)."""
    try:
        with library.writes.begin() as session:
            notes = notes or {}
            found = clip_db.update_clip(
                session,
                clip_id,
                name=name,
                labels=labels,
                source=notes.get("source", clip_db.UNSET),
                licence=notes.get("licence", clip_db.UNSET),
            )
    except SQLAlchemyError as exc:
        raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
    if not found:
        raise NotFound(f"no clip with id {clip_id}")
    library.sync_indexes()  # searches here show the new name and labels at once
    library.edits += 1
    return get_clip(library, clip_id)


def delete_clip(library: Library, clip_id: int) -> None:
    """Delete the row (vectors and labels go with it), then its vectors from every index, then
    the stored files no other clip uses."""
    with library.write_lock:
        try:
            with library.writes.begin() as session:
                hashes = clip_db.content_hashes(session, [clip_id])
                shas = clip_db.delete_clip(session, clip_id)
        except SQLAlchemyError as exc:
            raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
        if shas is None:
            raise NotFound(f"no clip with id {clip_id}")
        _tidy_after_delete(library, [clip_id], shas, hashes)


def _deletion(selection: ClipFilter | label_db.LabelFilter, doing: str = "delete") -> ClipFilter:
    if not isinstance(selection, ClipFilter):
        selection = ClipFilter.of(label=selection)
    if not selection:
        # Name what was sent (licence=! blamed 'label'); 'label' when nothing was.
        sent = ", ".join(selection.given)
        if sent:
            raise InvalidInput(
                f"{sent}: selects no clip (an empty value, blanks or a bare '!' are no filter); "
                f"name the label(s), licence(s), words (q) or ids of the clips to {doing}"
            )
        raise InvalidInput(f"label: name the label(s) (or id, licence, q) of the clips to {doing}")
    return selection


def clips_with_labels(
    library: Library, selection: ClipFilter | label_db.LabelFilter, *, doing: str = "delete"
) -> list[int]:
    """Ids of the clips ``selection`` keeps — the clips carrying every label of it, when it
    is a label filter (see :func:`delete_clips_with`); an empty one is refused, saying what
    the clips were chosen to ``doing``."""
    chosen = _deletion(selection, doing)
    with library.reads() as session:
        return selected_ids(session, chosen)


def delete_clips_with(library: Library, selection: ClipFilter | label_db.LabelFilter) -> int:
    """Delete every clip ``selection`` keeps — every clip carrying all its labels (compared
    case-insensitively) when it is a label filter — in one transaction, as
    :func:`delete_clip` does one; returns how many. An empty selection is refused."""
    chosen = _deletion(selection)
    with library.write_lock:
        try:
            with library.writes.begin() as session:
                ids = selected_ids(session, chosen)
                hashes = clip_db.content_hashes(session, ids)
                shas = clip_db.delete_clips(session, ids)
        except SQLAlchemyError as exc:
            raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
        if ids:
            _tidy_after_delete(library, ids, shas, hashes)
    return len(ids)


def _tidy_after_delete(
    library: Library, clip_ids: list[int], shas: list[str], content_hashes: list[str]
) -> None:
    """Committed: the clips are gone. Drop them from the indexes, remove the files no clip
    uses and the clips' stored previews; a failure here (a full disk, say) must not report
    the delete as failed."""
    what = f"clip {clip_ids[0]}" if len(clip_ids) == 1 else f"{len(clip_ids)} clips"
    for name, index in library.indexes.items():
        try:
            index.remove(clip_ids)  # from memory first, then the file is saved
        except OSError as exc:
            log.warning(
                "%s deleted, but the %s index could not be saved (%s); it is brought "
                "up to date from the database at the next start",
                what,
                name,
                exc,
            )
    drop_clip_windows(library, clip_ids)
    library.catalogue.apply_changes(np.asarray(clip_ids, np.int64), {})
    try:
        # In a write transaction: another process may be committing a clip against one.
        with library.writes.begin() as session:
            library.blobs.release(session, shas)
    except (SQLAlchemyError, OSError) as exc:
        log.warning(
            "%s deleted, but its files could not be removed (%s); they go at a later "
            "start (MOCAP_ORPHAN_FILE_GRACE_SECONDS)",
            what,
            exc,
        )
    try:
        preview_store(library.settings).remove(content_hashes)
    except OSError as exc:
        log.warning("%s deleted, but its stored previews could not be removed (%s)", what, exc)


def stored_bytes(library: Library, clip: clip_db.ClipRecord, sha256: str) -> bytes:
    """One stored file of ``clip``; :class:`NotFound` when the clip was deleted since its
    record was read (its files went with it: a download or an export racing a delete), not
    the 503 of a data directory that cannot be read."""
    try:
        return library.blobs.read(sha256)
    except StorageUnavailable:
        with library.reads() as session:
            gone = clip_db.get_clip(session, clip.id) is None
        if gone:
            raise NotFound(f"clip {clip.id} was deleted while it was being read") from None
        raise


def stored_upload(library: Library, clip: clip_db.ClipRecord) -> Upload:
    """A stored clip's files as the upload they came in (FBX/glTF: its own animation)."""
    if not clip.files:  # synthetic benchmark clips have vectors but no upload
        raise NotFound(f"clip {clip.id} has no stored file ({clip.format} clip)")
    data = {f.role: (f.filename, stored_bytes(library, clip, f.sha256)) for f in clip.files}
    return Upload.from_files(**data, animation=clip.animation)  # type: ignore[arg-type]


def clip_bvh(
    library: Library, clip: clip_db.ClipRecord, frames: tuple[int, int] | None = None
) -> Download:
    """Any clip as a BVH file of its own skeleton (read again from its stored files; FBX and
    glTF in a parser worker), optionally frames ``start:stop`` of it."""
    upload = stored_upload(library, clip)
    motion = read_motion(upload, library.settings.parse_limits, library.parsers).motion
    text = write_bvh(motion, frames)
    stem = PurePosixPath(upload.parts[-1].filename).stem or f"clip-{clip.id}"
    if clip.animation is not None and len(clip.animations or ()) > 1:
        stem = f"{stem} - {clip.animation}"
    name = f"{stem}.bvh"
    if frames is not None:
        name = _cut_name(name, frames[0] * clip.frame_time, frames[1] * clip.frame_time)
    return Download(name, "application/octet-stream", text.encode())


def _cut_name(filename: str, start: float, end: float) -> str:
    path = PurePosixPath(filename)
    return f"{path.stem}_{start:.2f}-{end:.2f}s{path.suffix}"


def _cut_part(
    library: Library, clip: clip_db.ClipRecord, record: clip_db.FileRecord, frames: tuple[int, int]
) -> tuple[str, bytes]:
    """A stored part cut to ``frames`` ``[first, stop)`` (the skeleton unchanged)."""
    data = stored_bytes(library, clip, record.sha256)
    if record.role == "skeleton":
        return record.filename, data
    cut = cut_bvh if record.role == "file" else cut_amc
    try:
        text = cut(decode_text(data), *frames)
    except (ParseError, ValueError) as error:
        raise InvalidInput(f"clip {clip.id}'s {record.role} cannot be cut: {error}") from None
    first, stop = frames
    name = _cut_name(record.filename, first * clip.frame_time, stop * clip.frame_time)
    return name, text.encode()


def clip_download(
    library: Library,
    clip: clip_db.ClipRecord,
    part: str | None,
    start: float | None = None,
    end: float | None = None,
    *,
    as_bvh: bool = False,
) -> Download:
    """The original upload: the file itself, or for ASF/AMC a ZIP of both files — or one
    ``part`` (``"file"``, ``"skeleton"``, ``"motion"``) byte for byte; with ``as_bvh`` the clip
    as a BVH file (:func:`clip_bvh`). With ``start`` and/or ``end`` (seconds from the first
    frame) the motion is cut to that span: BVH and ASF/AMC in their own format (see
    :mod:`app.motion.formats.cut`); FBX and glTF, which cannot be cut as they are, as the BVH
    export of the span."""
    if not clip.files:  # synthetic benchmark clips have vectors but no upload
        raise NoStoredFile(clip.id, clip.format)
    roles = {f.role: f for f in clip.files}
    if as_bvh and part is not None:
        raise InvalidInput("part: not with format=bvh (a BVH export is one file)")
    if part is not None and part not in roles:
        if len(roles) == 1:
            (only,) = roles.values()
            raise InvalidInput(
                f"part: clip {clip.id} is a single {clip.format.upper()} file "
                f"({only.filename}); leave out 'part' or use part={only.role}"
            )
        raise InvalidInput(f"part: clip {clip.id} has the parts {', '.join(roles)}")
    frames = None
    if start is not None or end is not None:
        frames = span_frames(clip.frame_count, clip.frame_time, 0, start, end)
    if as_bvh or (frames is not None and clip.format not in (BVH, ASF_AMC)):
        return clip_bvh(library, clip, frames)
    if frames is not None:
        wanted = [roles[part]] if part is not None else list(clip.files)
        cut = [_cut_part(library, clip, record, frames) for record in wanted]
        if len(cut) == 1:
            return Download(cut[0][0], "application/octet-stream", cut[0][1])
        return _zip(clip, cut, cut[-1][0])
    if part is not None or clip.format == BVH or len(clip.files) == 1:
        record = roles[part] if part is not None else clip.files[0]
        return Download(
            record.filename, "application/octet-stream", stored_bytes(library, clip, record.sha256)
        )
    motion = roles.get("motion", clip.files[-1])
    files = [(record.filename, stored_bytes(library, clip, record.sha256)) for record in clip.files]
    return _zip(clip, files, motion.filename)


def _zip(clip: clip_db.ClipRecord, files: list[tuple[str, bytes]], named_after: str) -> Download:
    """A ZIP of ``files`` (name, bytes), called like ``named_after``."""
    buffer = io.BytesIO()
    stamp = clip.created_at.timetuple()[:6]
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for filename, data in files:
            info = zipfile.ZipInfo(filename, date_time=stamp)
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, data)
    return Download(f"{PurePosixPath(named_after).stem}.zip", "application/zip", buffer.getvalue())


def remove_orphan_files(library: Library) -> int:
    """Delete stored files no clip refers to, and temporary files, once older than
    ``MOCAP_ORPHAN_FILE_GRACE_SECONDS``; returns how many went.

    A crash between writing an upload's files and committing its clip, or between deleting a
    clip and removing its files, leaves such files. On SQLite the database write lock is held
    while looking (``BEGIN IMMEDIATE``), so no clip commits meanwhile; on PostgreSQL one
    statement removes the unreferenced rows of ``blobs``. Either way the grace spares the files
    another process (a replica, an import) wrote and has not committed yet.
    """
    settings = library.settings
    cutoff = time.time() - settings.orphan_file_grace_seconds
    with library.write_lock:
        try:
            with library.writes.begin() as session:
                removed = library.blobs.remove_unreferenced(session, older_than=cutoff)
        except SQLAlchemyError as exc:
            log.warning("could not look for unreferenced stored files: %s", exc)
            return 0
        except OSError as exc:
            log.warning("could not remove unreferenced stored files: %s", exc)
            return 0
    # Index files half-written by a crash (the index module writes to a temporary name).
    for path in settings.index_dir.glob(".*.tmp") if settings.index_dir.is_dir() else ():
        try:
            if path.stat().st_mtime < cutoff:
                path.unlink()
                removed += 1
        except OSError:
            continue
    if removed:
        log.warning(
            "removed %d stored or temporary files no clip refers to (left by an interrupted "
            "upload or delete)",
            removed,
        )
    return removed
