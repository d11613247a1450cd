"""Ingest: uploaded bytes -> parse -> describe -> store files -> database commit -> indexes
-> stored previews.

Order matters. The files are written before the rows that name them, the database commits
before the indexes change (the database is the source of truth: an index can be rebuilt from
it, not the other way round), and a failure before the commit leaves no row, no vector and
no file behind. Identical content (same content hash) is stored once: a repeated upload returns
the existing clip after applying what it brings (its labels are added, its name, source and
licence replace the stored ones; :func:`apply_to_stored`), also when two arrive at once (the
UNIQUE content hash settles races with other processes; the library's write lock those within
this one).

:func:`store_many` is the one way clips are stored: a batch of described uploads goes in one
transaction (a few multi-row INSERTs), then the indexes follow the database
(:meth:`Library.sync_indexes`: one add per index for the batch), and the previews the
describer made are written (a cache: one that cannot be written is logged, never an error;
:mod:`app.services.previews`). ``POST /clips`` stores a batch
of one (:func:`ingest`); ``mocap-index import`` (:mod:`app.importer`) describes clips in
worker processes and stores them here in batches; :func:`ingest_many` does both in-process.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy.exc import IntegrityError, SQLAlchemyError

from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.db import windows as window_db
from app.errors import InvalidInput, MocapError, StorageUnavailable
from app.labels import MAX_LABELS, merge_labels
from app.services.describe import Description
from app.services.library import Library
from app.services.previews import save_stored_preview
from app.services.uploads import Upload, UploadPart

log = logging.getLogger(__name__)

MAX_COMMIT_ATTEMPTS = 3


@dataclass(frozen=True)
class Described:
    """An upload the motion core has read and described, ready to be stored.

    ``description`` is ``None`` for content found already stored, which need not be read.
    """

    upload: Upload
    description: Description | None


@dataclass(frozen=True)
class IngestResult:
    clip: clip_db.ClipRecord
    created: bool  # False: the same content was already stored, ``clip`` is that clip
    changed: bool = False  # a duplicate whose labels, name, source or licence were applied


def get_stored(library: Library, clip_id: int) -> clip_db.ClipRecord:
    with library.reads() as session:
        clip = clip_db.get_clip(session, clip_id)
    if clip is None:  # deleted by another request meanwhile
        raise StorageUnavailable("the clip was deleted while it was being changed; try again")
    return clip


def find_existing(library: Library, upload: Upload) -> clip_db.ClipRecord | None:
    with library.reads() as session:
        return clip_db.get_clip_by_hash(session, upload.content_hash)


def describe(library: Library, upload: Upload, *, only: Sequence[str] | None = None) -> Described:
    """Parse and describe ``upload`` (blocking, CPU-bound; stores nothing). An FBX/glTF
    upload comes back knowing which animation it holds (and so its content hash)."""
    description = library.describer.describe(upload, library.settings.parse_limits, only=only)
    return Described(described_upload(upload, description), description)


def described_upload(upload: Upload, description: Description) -> Upload:
    """``upload`` with the animation its description read (FBX/glTF), else as it is."""
    if description.animation is None:
        return upload
    return upload.with_animations(description.animations, description.animation)


def animation_records(upload: Upload) -> tuple[clip_db.AnimationRecord, ...] | None:
    """The file's animations as stored with the clip (None for BVH and ASF/AMC)."""
    if upload.animation is None:
        return None
    return tuple(
        clip_db.AnimationRecord(a.name, a.frame_count, a.duration, a.name == upload.animation)
        for a in upload.animations
    )


def new_clip(library: Library, item: Described) -> clip_db.NewClip:
    """The row to insert for a described upload."""
    upload, description = item.upload, item.description
    if description is None:
        raise ValueError("the upload was not described")
    return clip_db.NewClip(
        name=upload.clip_name,
        format=upload.format,
        content_hash=upload.content_hash,
        frame_count=description.frame_count,
        frame_time=description.frame_time,
        duration=description.duration,
        joint_count=description.joint_count,
        skeleton_family=description.skeleton_family,
        lead_in_frames=description.lead_in_frames,
        warnings=description.warnings,
        joint_mapping=description.joint_mapping,
        labels=upload.labels,
        source=upload.source,
        licence=upload.licence,
        files=tuple(clip_db.FileRecord(p.role, p.filename, p.sha256, p.size) for p in upload.parts),
        vectors={
            name: vector_db.StoredVector(library.descriptors[name].version, vector)
            for name, vector in description.vectors.items()
        },
        windows=new_windows(library, description),
        animations=animation_records(upload),
    )


def new_windows(library: Library, description: Description) -> tuple[window_db.NewWindows, ...]:
    """The window rows of a described clip (none when it was described without windows or
    the library keeps none)."""
    windows = description.windows
    if windows is None or not library.window_keys:
        return ()
    lengths = np.asarray(windows.lengths, dtype=np.float64)[windows.spans[:, 0]]
    return tuple(
        window_db.NewWindows(
            name=name,
            version=library.descriptors[name].version,
            lengths=lengths,
            starts=windows.spans[:, 1],
            stops=windows.spans[:, 2],
            vectors=vectors,
        )
        for name, vectors in windows.vectors.items()
    )


def _forget_files(library: Library, written: Iterable[str]) -> None:
    """Remove files this call wrote (they did not exist before) that no committed clip uses,
    in a write transaction (:meth:`BlobStore.release`: another process may be committing a
    clip against one of them)."""
    written = set(written)
    if not written:
        return
    try:
        with library.writes.begin() as session:
            library.blobs.release(session, written)
    except SQLAlchemyError:
        # The database is down: only another process could have referred to these new files
        # meanwhile, far less likely than this failure, so they go.
        for sha in written:
            library.blobs.delete(sha)


def _unique_files(parts: Sequence[UploadPart]) -> list[tuple[bytes, str]]:
    """``(data, sha256)`` of each distinct content among ``parts`` (hashed once)."""
    return [(part.data, part.sha256) for part in {part.sha256: part for part in parts}.values()]


def _put_files(library: Library, parts: Sequence[UploadPart], written: list[str]) -> None:
    """Store the files of ``parts``, appending to ``written`` the sha256 of those that were
    new; all or none are stored."""
    stored = library.blobs.put_many(_unique_files(parts))
    written.extend(sha for sha, new in stored if new)


def store_many(library: Library, items: Sequence[Described]) -> list[IngestResult]:
    """Store described uploads in one transaction; results in the order of ``items``.

    Content already stored (or repeated within ``items``) is not stored again: its result is
    the existing clip with ``created=False``.
    """
    if not items:
        return []
    hashes = [item.upload.content_hash for item in items]
    created: set[str] = set()
    stored: list[Described] = []
    with library.write_lock:
        for attempt in range(1, MAX_COMMIT_ATTEMPTS + 1):
            with library.reads() as session:
                existing = clip_db.clip_ids_by_hash(session, hashes)
            fresh: dict[str, Described] = {}
            for item in items:
                if item.upload.content_hash not in existing:
                    fresh.setdefault(item.upload.content_hash, item)
            if not fresh:
                break
            for content_hash, item in fresh.items():
                if item.description is None:  # found stored earlier, deleted since: read it now
                    fresh[content_hash] = describe(library, item.upload)
            written: list[str] = []
            try:
                parts = [p for i in fresh.values() for p in i.upload.parts]
                _put_files(library, parts, written)
                rows = [new_clip(library, item) for item in fresh.values()]
                with library.writes.begin() as session:
                    # Another process may have removed a file found stored: write it again.
                    written.extend(library.blobs.claim(session, _unique_files(parts)))
                    clip_db.insert_clips(session, rows)
            except IntegrityError:
                # Another process stored some of this content meanwhile: look again.
                _forget_files(library, written)
                if attempt == MAX_COMMIT_ATTEMPTS:
                    raise StorageUnavailable("the database kept changing; try again") from None
                continue
            except SQLAlchemyError as exc:
                _forget_files(library, written)
                raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
            except BaseException:
                _forget_files(library, written)
                raise
            created, stored = set(fresh), list(fresh.values())
            # Committed: now the indexes (they take every clip committed so far, from here or
            # from another process).
            library.sync_indexes()
            break
        with library.reads() as session:
            by_hash = clip_db.clip_ids_by_hash(session, hashes)
        changed = apply_to_stored(
            library,
            [
                (by_hash[item.upload.content_hash], item.upload)
                for item in items
                if item.upload.content_hash not in created and item.upload.content_hash in by_hash
            ],
            refuse_over_cap=len(items) == 1,  # one upload gets its 422; a batch goes on
        )
        with library.reads() as session:
            clips = clip_db.get_clips(session, by_hash.values())
    _save_previews(library, stored)
    results = []
    reported: set[str] = set()
    for content_hash in hashes:
        is_new = content_hash in created and content_hash not in reported
        reported.add(content_hash)
        clip_id = by_hash[content_hash]
        results.append(IngestResult(clips[clip_id], is_new, clip_id in changed))
    return results


def _save_previews(library: Library, stored: Sequence[Described]) -> None:
    """Store the previews the describer made of clips just committed (outside the write
    lock: a cache the commit does not wait on), so a page's first view of them reads a
    small file instead of parsing the clip again (:mod:`app.services.previews`)."""
    for item in stored:
        if item.description is not None and item.description.preview is not None:
            save_stored_preview(library, item.upload.content_hash, item.description.preview)


def apply_to_stored(
    library: Library, duplicates: Sequence[tuple[int, Upload]], *, refuse_over_cap: bool = True
) -> set[int]:
    """Apply to already-stored clips what repeated uploads of their content bring: labels are
    added (those the clip lacks, in any case), a given name, source or licence replaces the
    stored one. One transaction; returns the ids of the clips that changed.

    Labels that would take a clip past :data:`~app.labels.MAX_LABELS` are refused
    (:class:`InvalidInput`, nothing applied), or with ``refuse_over_cap=False`` (a batch of
    an import, which one clip must not fail) left out, the stored ones kept, with a warning.
    """
    wanted = [(clip_id, upload) for clip_id, upload in duplicates if _brings_something(upload)]
    if not wanted:
        return set()
    changed: set[int] = set()
    try:
        with library.writes.begin() as session:
            stored = clip_db.get_clips(session, [clip_id for clip_id, _ in wanted])
            for clip_id, upload in wanted:
                clip = stored.get(clip_id)
                if clip is None:
                    continue
                labels = _capped(clip, merge_labels(clip.labels, upload.labels), refuse_over_cap)
                updates: dict[str, Any] = {}
                if labels != clip.labels:
                    updates["labels"] = labels
                for key in ("name", "source", "licence"):
                    value = getattr(upload, key)
                    if value is not None and value != getattr(clip, key):
                        updates[key] = value
                if updates:
                    clip_db.update_clip(session, clip_id, **updates)
                    stored[clip_id] = dataclasses.replace(clip, **updates)
                    changed.add(clip_id)
    except SQLAlchemyError as exc:
        raise StorageUnavailable(f"cannot write to the database: {exc}") from exc
    if changed:
        library.sync_indexes()  # searches here show the new name and labels at once
        library.edits += 1
    return changed


def _capped(clip: clip_db.ClipRecord, labels: tuple[str, ...], refuse: bool) -> tuple[str, ...]:
    """``labels`` (the stored ones first) when within the cap; else refused or cut."""
    if len(labels) <= MAX_LABELS:
        return labels
    added = len(labels) - len(clip.labels)
    message = (
        f"labels: clip {clip.id} carries {len(clip.labels)} labels; the {added} new ones of "
        f"this upload would make {len(labels)}, over the cap of {MAX_LABELS} labels per clip"
    )
    if refuse:
        raise InvalidInput(message)
    log.warning("%s: kept the first %d", message, MAX_LABELS)
    return labels[: max(MAX_LABELS, len(clip.labels))]


def _brings_something(upload: Upload) -> bool:
    return bool(upload.labels) or any(
        value is not None for value in (upload.name, upload.source, upload.licence)
    )


def ingest(library: Library, upload: Upload) -> IngestResult:
    """Store one upload (or return the clip already holding the same content)."""
    existing = find_existing(library, upload) if upload.knows_content_hash else None
    if existing is not None:  # no need to read it again
        if not apply_to_stored(library, [(existing.id, upload)]):
            return IngestResult(existing, created=False)
        return IngestResult(get_stored(library, existing.id), created=False, changed=True)
    return store_many(library, [describe(library, upload)])[0]


def ingest_many(
    library: Library,
    uploads: Iterable[Upload],
    *,
    batch_size: int = 100,
    on_error: Callable[[Upload, MocapError], None] | None = None,
) -> list[IngestResult]:
    """Store many uploads, ``batch_size`` per transaction and index update.

    An upload that cannot be read raises, unless ``on_error`` is given: then it is reported
    there and skipped (the batch goes on). Results are in upload order, skipped ones left out.
    """
    results: list[IngestResult] = []
    batch: list[Described] = []
    for upload in uploads:
        try:
            if not upload.knows_content_hash or find_existing(library, upload) is None:
                batch.append(describe(library, upload))
            else:
                batch.append(Described(upload, None))
        except MocapError as error:
            if on_error is None:
                raise
            on_error(upload, error)
            continue
        if len(batch) >= batch_size:
            results.extend(store_many(library, batch))
            batch = []
    results.extend(store_many(library, batch))
    return results
