"""One descriptor's FAISS index and its files: saving (now, or batched after a delay) and
reading the saved index back.

Files: saves write a temporary file and rename it, under an exclusive ``fcntl.flock`` on
``<dir>/.lock`` (loads take it shared), so two processes (the server and ``mocap-index
import``) never interleave the ``.faiss`` and ``.json`` of one index. The ``.json`` records
``feed_position`` (``synced_to`` in the code), the position in the database's change feed the
saved index reflects. An IVF index, once written, is mapped from its file (see
:mod:`app.index.frozen`) instead of held as a copy. The files themselves are
:class:`app.index.index_file.IndexFile`; keeping the index in step with the database is
:class:`app.index.descriptor_index.DescriptorIndex`'s work, which builds on this class.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import faiss

from app.index.delayed_save import DelayedSave
from app.index.frozen import FrozenIVF
from app.index.held_index import HeldIndex
from app.index.index_file import IndexFile
from app.index.kinds import FLOAT32, IVF, SQ8, IndexOptions
from app.index.locks import directory_lock

log = logging.getLogger(__name__)


class SavedIndex(HeldIndex, DelayedSave):
    """The index of one descriptor saved to its files; what it holds and its searches are
    :class:`HeldIndex`'s.

    Parameters
    ----------
    name, dimension, version:
        The descriptor (as in the registry); only vectors of this version are held.
    directory:
        Where ``<name>.faiss`` and ``<name>.json`` are written.
    index:
        A FAISS index to start from (default: an empty flat one).
    options:
        Index kind and search settings.
    searched_by_clip:
        Whether searches by clip ask it (a clip index; not the moments' window indexes, only
        searched in batches): a file it writes then has its adaptive probe and cells' graph
        decided before it is used (:meth:`FrozenIVF.prepare`), not by its first search.
    """

    def __init__(
        self,
        name: str,
        dimension: int,
        version: int,
        directory: Path,
        index: Any | None = None,
        options: IndexOptions | None = None,
        *,
        searched_by_clip: bool = True,
    ) -> None:
        super().__init__(dimension, index, options)
        self.searched_by_clip = searched_by_clip
        self.name = name
        self.version = version
        self.directory = directory
        self.file = IndexFile(name, dimension, version, directory)
        self._init_saving()
        self.autosave = True  # False: changes are saved only by an explicit save()
        self._save_lock = threading.Lock()

    @property
    def path(self) -> Path:
        return self.file.path

    @property
    def meta_path(self) -> Path:
        return self.file.meta_path

    def _autosave(self, persist: bool | None) -> None:
        if persist:
            self.try_save()
        elif persist is None and self.autosave and self.size <= self.options.autosave_below:
            if self.options.save_delay <= 0:
                self.try_save()
            else:
                self._schedule_save(self.options.save_delay)

    def try_save(self) -> bool:
        """:meth:`save`, logging instead of raising when the file cannot be written (the
        index in memory is right; a file that is behind catches up when it is next loaded).
        Returns whether it was saved."""
        try:
            self.save()
        except (OSError, RuntimeError) as exc:  # FAISS reports unwritable files as RuntimeError
            log.warning(
                "could not save the %s index (%s); it catches up from the database when next "
                "loaded",
                self.name,
                exc,
            )
            return False
        return True

    def save(self) -> None:
        """Write the index and its metadata atomically (temp file, then rename), under the
        directory's exclusive file lock; then map the file (IVF; see app/index/frozen.py)
        instead of holding a copy, when nothing changed meanwhile."""
        # The save lock keeps two saves in order: the last state serialised is the one written.
        with self._save_lock:
            written = self._write_and_map()
            if written is None:  # only the feed position moved on
                return
            index, unsaved, mapped = written
            if mapped is not None and self.searched_by_clip:
                # Decided here, not by the first search (outside the directory's lock: it is
                # taken again to store them beside the file)
                mapped.prepare(self.options.nprobe or mapped.base_nprobe)
            with self._lock.write():
                if mapped is not None and self._index is index and self._unsaved == unsaved:
                    self._index = mapped  # nothing changed while writing: share the file
                    self._sorted = None
                self._unsaved = max(0, self._unsaved - unsaved)

    def _write_and_map(self) -> tuple[Any, int, FrozenIVF | None] | None:
        """:meth:`save`'s file work, under the directory's exclusive lock: the index written
        (``(index, its unsaved count then, the file mapped or None)``), or only the feed
        position (None) when the mapped file holds its vectors already."""
        with directory_lock(self.directory, exclusive=True):
            with self._lock.read():
                index = self._index
                count = int(index.ntotal)
                kind = self.kind
                nprobe = self.nprobe
                synced_to = self._synced_to
                unsaved = self._unsaved
                if (
                    isinstance(index, FrozenIVF)
                    and index.mapped_from is not None
                    and not index.changed
                    and self.file.is_mapped_file()
                ):
                    # The file holds these vectors: only the feed position moves on.
                    self.file.write_meta(dict(self.file.mapped_meta, feed_position=synced_to))
                    self._unsaved = max(0, self._unsaved - unsaved)
                    return None
                written = index.merged() if isinstance(index, FrozenIVF) else index
                if isinstance(index, FrozenIVF) and index.exact is not None:
                    # a copy, mapped once written: no id hash table for FAISS to rebuild
                    written.set_direct_map_type(faiss.DirectMap.NoMap)  # type: ignore[attr-defined]
                exact = (
                    index.all_vectors()
                    if isinstance(index, FrozenIVF) and index.exact is not None
                    else None
                )
                tmp = self.file.write_temporary(written)
            del written
            # The exact vectors go first: an index file never lacks them.
            meta = self.file.install(
                tmp,
                {
                    "descriptor": self.name,
                    "version": self.version,
                    "dimension": self.dimension,
                    "kind": kind,
                    "codes": FLOAT32 if exact is None else SQ8,
                    "nprobe": nprobe,
                    "count": count,
                    "feed_position": synced_to,
                },
                exact,
            )
            del exact
            maps = kind == IVF and self.file.maps(meta, mmap=self.options.mmap)
            return index, unsaved, self.file.map(meta) if maps else None

    def read_file(self, *, verify: bool = True) -> tuple[Any, dict[str, Any]] | str:
        """The persisted index and its metadata, or why they cannot be used (file work only:
        several indexes can be read at once, in threads). An IVF index is mapped, not read
        (see app/index/frozen.py); with ``verify=False`` its checksum is checked later, by
        :meth:`verify_file` (hashing a large file is most of a server's start-up)."""
        return self.file.read(verify=verify, mmap=self.options.mmap)

    def verify_file(self) -> str | None:
        """Check the checksum of the file mapped by ``read_file(verify=False)``: why it cannot
        be used (the caller rebuilds the index), or None."""
        return self.file.verify()
