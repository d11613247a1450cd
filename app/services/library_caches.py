"""Opening the library's in-memory caches at start: every descriptor's clip index, the window
indexes of moments search (one per windowed descriptor and window length) and the catalogue.

Their files are read (and checksummed) at once, in threads; then, at one feed position taken
before the database's rows, each is brought up to date with the database from its file, or
rebuilt from it when the file is missing, damaged, stale or older than the change feed keeps
(:meth:`app.index.descriptor_index.DescriptorIndex.load_or_rebuild`,
:meth:`app.index.catalogue.Catalogue.load_or_rebuild`). :func:`app.services.library.open_library`
calls :func:`open_caches`; the :class:`~app.services.library.Library` keeps them current.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import windows as window_db
from app.db.changes import horizon, pruned_before
from app.index.catalogue import Catalogue
from app.index.descriptor_index import DescriptorIndex
from app.index.index_set import IndexSet
from app.index.kinds import IndexOptions
from app.index.sources import StoredClips, StoredVectors, StoredWindows
from app.services.describe import WINDOW_DESCRIPTORS, WINDOW_LENGTHS, DescriptorInfo

log = logging.getLogger(__name__)

WINDOW_IVF_FROM = 20_000  # windows from which a window index is IVF (or MOCAP_INDEX_AUTO_...)


def index_options(settings: Settings) -> IndexOptions:
    """The index kind and search settings of ``MOCAP_INDEX_TYPE`` and friends."""
    return IndexOptions(
        kind=settings.index_type,
        auto_threshold=settings.index_auto_threshold,
        nlist=settings.ivf_nlist,
        nprobe=settings.ivf_nprobe,
        codes=settings.clip_codes,
    )


def window_index_name(descriptor: str, length: float) -> str:
    """File stem of the index of ``descriptor`` windows of ``length`` seconds."""
    return f"windows-{descriptor}-{length:g}s"


def window_keys(
    settings: Settings, descriptors: Mapping[str, DescriptorInfo]
) -> dict[str, window_db.WindowKey]:
    """Every window index: its name -> which windows it holds (the descriptors of
    :data:`WINDOW_DESCRIPTORS` the describer has, at each of :data:`WINDOW_LENGTHS`; none
    when MOCAP_MOMENTS is off)."""
    if not settings.moments:
        return {}
    return {
        window_index_name(name, length): window_db.WindowKey(
            name, descriptors[name].version, descriptors[name].dimension, length
        )
        for name in WINDOW_DESCRIPTORS
        if name in descriptors
        for length in WINDOW_LENGTHS
    }


def open_caches(
    settings: Settings,
    reads: sessionmaker[Session],
    descriptors: Mapping[str, DescriptorInfo],
    *,
    verify: bool = True,
) -> tuple[IndexSet, IndexSet, Catalogue]:
    """The clip indexes, the window indexes and the catalogue, loaded (or rebuilt) from their
    files (``verify=False``: the mapped files' checksums are left to
    :meth:`Library.verify_files`)."""
    options = index_options(settings)
    indexes = {
        info.name: DescriptorIndex(
            info.name, info.dimension, info.version, settings.index_dir, options=options
        )
        for info in descriptors.values()
    }
    keys = window_keys(settings, descriptors)
    # A moments search asks one or two window indexes for ~140 windows each: a flat scan of
    # the 90,000 8-s windows of 100 hours was a sixth of it. IVF from fewer windows.
    window_options = dataclasses.replace(
        options,
        auto_threshold=min(options.auto_threshold, WINDOW_IVF_FROM),
        codes=settings.window_codes,
    )
    windows = {
        name: DescriptorIndex(
            name,
            key.dimension,
            key.version,
            settings.index_dir,
            options=window_options,
            searched_by_clip=False,
        )
        for name, key in keys.items()
    }
    catalogue = Catalogue(
        settings.index_dir, autosave_below=options.autosave_below, save_delay=options.save_delay
    )
    # Reading and checksumming the files (hundreds of MB at a million clips) releases the
    # GIL: all at once, in threads.
    every = [*indexes.values(), *windows.values()]
    with ThreadPoolExecutor(max_workers=max(1, min(8, len(every) + 1))) as pool:
        listed = pool.submit(catalogue.read_file, verify=verify)
        files = dict(zip(every, pool.map(lambda i: i.read_file(verify=verify), every), strict=True))
        catalogue_file = listed.result()
    fresh = all(isinstance(found, str) for found in files.values())  # no index file at all
    with reads() as session:  # one feed position for every index, taken before their vectors
        watermark = horizon(session)
        pruned = pruned_before(session)
        for info in descriptors.values():
            source = StoredVectors(session, info, watermark)
            index = indexes[info.name]
            index.load_or_rebuild(source, _followable(files.pop(index), pruned))
        for name, key in keys.items():
            index = windows[name]
            found = _followable(files.pop(index), pruned)
            stored = StoredWindows if verify else _WindowsCountedLater
            index.load_or_rebuild(stored(session, key, watermark, index), found)
        found = _followable(catalogue_file, pruned)
        catalogue.load_or_rebuild(StoredClips(session, watermark), found)
    if fresh and not any(index.size for index in every):
        log.info("new library: created its %d empty indexes in %s", len(every), settings.index_dir)
    return IndexSet(indexes), IndexSet(windows), catalogue


class _WindowsCountedLater(StoredWindows):
    """:class:`StoredWindows` whose count is the index's own: a server's start does not
    count the windows in the database (see :meth:`Library.check_window_counts`, which its
    verifier thread runs; files it cannot follow are still rebuilt at once)."""

    def __init__(
        self, session: Session, key: window_db.WindowKey, watermark: int, index: DescriptorIndex
    ) -> None:
        super().__init__(session, key, watermark, index)
        self._held = index

    def count(self) -> int:
        return self._held.size


def _followable(found: tuple[Any, dict[str, Any]] | str, pruned: int) -> Any:
    """An index file as read (:meth:`DescriptorIndex.read_file`), or why it cannot be
    brought up to date from the change feed: saved before the rows the feed keeps (the
    process was away longer than the retention), it is rebuilt from the database."""
    if isinstance(found, tuple):
        position = found[1].get("feed_position")
        if isinstance(position, int) and position < pruned:
            return (
                "the index file is older than the change feed keeps (MOCAP_CHANGE_RETENTION_HOURS)"
            )
    return found
