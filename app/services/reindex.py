"""Recompute descriptor vectors from the stored files, then rebuild every index.

Needed when a descriptor's version changes or a new descriptor is registered: stored clips
then lack a current vector and cannot be found with it until this runs (searches under a
descriptor with outdated vectors answer 409 meanwhile). A clip whose vectors cannot be
recomputed (its file no longer reads, or a synthetic clip without a file) loses its outdated
vectors, so the library is current afterwards; it is reported, and stays listed and
downloadable.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.db import windows as window_db
from app.errors import InvalidInput, MocapError
from app.services.clips import stored_upload
from app.services.describe import Description, MotionDescriber
from app.services.ingest import new_windows
from app.services.library import Library
from app.services.previews import save_stored_preview
from app.services.uploads import Upload


@dataclass
class ReindexReport:
    recomputed: int = 0
    failed: dict[int, str] = field(default_factory=dict)  # clip id -> why
    index_sizes: dict[str, int] = field(default_factory=dict)


def describe_stored(
    library: Library, upload: Upload, names: list[str], windows: bool
) -> Description:
    """Describe a stored clip under ``names`` (and its windows when ``windows``); the motion
    core's describer also makes its stored preview, from the body it builds anyway."""
    describer = library.describer
    limits = library.settings.parse_limits
    if isinstance(describer, MotionDescriber):
        return describer.describe(upload, limits, only=names or None, windows=windows, preview=True)
    return describer.describe(upload, limits, only=names)


def reindex(
    library: Library,
    *,
    everything: bool = False,
    progress: Callable[[int, int, clip_db.ClipRecord], None] | None = None,
) -> ReindexReport:
    """Recompute the vectors that are missing or of an old version (every vector with
    ``everything``), then rebuild and save each descriptor's index from the database.

    Run it while the service is stopped: a running service keeps its own indexes in memory.
    """
    current = {name: info.version for name, info in library.descriptors.items()}
    windowed = {key.name: key.version for key in library.window_keys.values()}
    with library.reads() as session:
        if everything:
            needing = {i: list(current) for i in clip_db.all_clip_ids(session)}
            windows_needed = set(needing)
        else:
            needing = vector_db.clips_needing_vectors(session, current)
            windows_needed = set(window_db.clips_needing_windows(session, windowed))
            for clip_id in windows_needed:
                needing.setdefault(clip_id, [])
    report = ReindexReport()
    for done, (clip_id, names) in enumerate(needing.items(), start=1):
        with library.reads() as session:
            clip = clip_db.get_clip(session, clip_id)
        if clip is None:  # deleted meanwhile
            continue
        if progress is not None:
            progress(done, len(needing), clip)
        with_windows = clip_id in windows_needed and bool(clip.files)
        try:
            if not clip.files:
                raise InvalidInput("a synthetic clip has no stored file to describe again")
            upload = stored_upload(library, clip)
            description = describe_stored(library, upload, names, with_windows)
        except InvalidInput as error:  # the clip cannot be described: its old vectors go
            report.failed[clip_id] = error.detail
            with library.write_lock, library.writes.begin() as session:
                vector_db.delete_vectors(session, clip_id, names)
            continue
        except MocapError as error:  # storage trouble: keep everything, run again later
            report.failed[clip_id] = error.detail
            continue
        vectors = {
            name: vector_db.StoredVector(current[name], vector)
            for name, vector in description.vectors.items()
        }
        with library.write_lock, library.writes.begin() as session:
            vector_db.put_vectors(session, clip_id, vectors)
            if with_windows:
                window_db.put_windows(session, clip_id, new_windows(library, description))
            clip_db.update_clip(session, clip_id, analysis=description.fields)
        if description.preview is not None:  # a new motion core names new previews
            save_stored_preview(library, clip.content_hash, description.preview)
        report.recomputed += 1
    with library.write_lock:
        for name in library.descriptors:
            library.rebuild_index(name)
    library.rebuild_window_indexes()
    report.index_sizes = {**library.indexes.sizes(), **library.window_indexes.sizes()}
    library.count_outdated()  # searches need not wait for the next recount
    return report
