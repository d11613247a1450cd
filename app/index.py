"""FAISS indexes: one exact ``IndexIDMap2(IndexFlatL2)`` per descriptor, ids = clip ids.

The database is the source of truth; an index is a cache of its vectors that can always be
rebuilt. Each index is persisted as ``<dir>/<descriptor>.faiss`` with a ``<descriptor>.json``
beside it recording the descriptor version, dimension, vector count and the sha256 of the
index file. :func:`open_index` loads it and rebuilds from the database when the file is
missing, unreadable, of another version or dimension, or holds other ids than the database.

Concurrency: searches share a read lock, add/remove take the write lock (a flat index must not
grow while it is being scanned), so a search sees a clip either entirely or not at all.

Shapes: a query is ``(D,)`` float32; batches are ``(N, D)`` float32 C-contiguous with ``(N,)``
int64 ids.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# FAISS reads OMP_NUM_THREADS once, when its OpenMP runtime loads, and a single query is not
# faster on more threads (STYLE.md): default to one before the import — this module is the only
# place faiss is imported, so every entry point (serve, uvicorn --factory, tests) gets it — but
# keep a value the operator set.
os.environ.setdefault("OMP_NUM_THREADS", "1")
import faiss

log = logging.getLogger(__name__)

LoadVectors = Callable[[], tuple[np.ndarray, np.ndarray]]
"""Returns ``(ids (N,) int64, vectors (N, D) float32)`` from the database."""


class ReadWriteLock:
    """Many readers or one writer. Waiting writers block new readers, so a steady stream of
    searches cannot starve an upload."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._readers = 0
        self._writer = False
        self._writers_waiting = 0

    @contextmanager
    def read(self) -> Iterator[None]:
        with self._cond:
            while self._writer or self._writers_waiting:
                self._cond.wait()
            self._readers += 1
        try:
            yield
        finally:
            with self._cond:
                self._readers -= 1
                if self._readers == 0:
                    self._cond.notify_all()

    @contextmanager
    def write(self) -> Iterator[None]:
        with self._cond:
            self._writers_waiting += 1
            try:
                while self._writer or self._readers:
                    self._cond.wait()
            finally:
                self._writers_waiting -= 1
            self._writer = True
        try:
            yield
        finally:
            with self._cond:
                self._writer = False
                self._cond.notify_all()


@dataclass(frozen=True)
class Neighbours:
    """Search results, nearest first: ``ids`` ``(n,)`` int64, ``distances`` ``(n,)`` float64
    Euclidean (not squared)."""

    ids: np.ndarray
    distances: np.ndarray

    def __len__(self) -> int:
        return int(self.ids.shape[0])


def _as_ids(ids: np.ndarray | list[int]) -> np.ndarray:
    return np.ascontiguousarray(ids, dtype=np.int64).reshape(-1)


def _as_vectors(vectors: np.ndarray, dimension: int) -> np.ndarray:
    array = np.ascontiguousarray(vectors, dtype=np.float32)
    if array.ndim == 1:
        array = array.reshape(1, -1)
    if array.ndim != 2 or array.shape[1] != dimension:
        raise ValueError(f"expected vectors of shape (N, {dimension}), got {vectors.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError("vectors must be finite")
    return array


def _empty_index(dimension: int) -> faiss.IndexIDMap2:
    return faiss.IndexIDMap2(faiss.IndexFlatL2(dimension))


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


class DescriptorIndex:
    """The index of one descriptor.

    Parameters
    ----------
    name, dimension, version:
        The descriptor (as in the registry); only vectors of this version are held.
    directory:
        Where ``<name>.faiss`` and ``<name>.json`` are written.
    """

    def __init__(
        self,
        name: str,
        dimension: int,
        version: int,
        directory: Path,
        index: faiss.IndexIDMap2 | None = None,
    ) -> None:
        self.name = name
        self.dimension = dimension
        self.version = version
        self.directory = directory
        self._index = index if index is not None else _empty_index(dimension)
        self._lock = ReadWriteLock()
        self._save_lock = threading.Lock()

    @property
    def path(self) -> Path:
        return self.directory / f"{self.name}.faiss"

    @property
    def meta_path(self) -> Path:
        return self.directory / f"{self.name}.json"

    @property
    def size(self) -> int:
        return int(self._index.ntotal)

    def ids(self) -> np.ndarray:
        """``(N,)`` int64 ids in the index, in insertion order."""
        with self._lock.read():
            return faiss.vector_to_array(self._index.id_map).astype(np.int64)

    def add(
        self, ids: np.ndarray | list[int], vectors: np.ndarray, *, persist: bool = True
    ) -> None:
        """Add ``vectors`` ``(N, D)`` under ``ids`` ``(N,)`` (ids must not be present yet)."""
        ids_ = _as_ids(ids)
        array = _as_vectors(vectors, self.dimension)
        if array.shape[0] != ids_.shape[0]:
            raise ValueError("ids and vectors differ in length")
        if ids_.size == 0:
            return
        with self._lock.write():
            self._index.add_with_ids(array, ids_)
        if persist:
            self.save()

    def remove(self, ids: np.ndarray | list[int], *, persist: bool = True) -> int:
        """Remove ``ids`` (absent ones are ignored); returns how many were removed."""
        ids_ = _as_ids(ids)
        if ids_.size == 0:
            return 0
        with self._lock.write():
            removed = int(self._index.remove_ids(faiss.IDSelectorBatch(ids_)))
        if persist and removed:
            self.save()
        return removed

    def search(
        self,
        query: np.ndarray,
        k: int,
        *,
        allowed: np.ndarray | None = None,
        exclude: int | None = None,
    ) -> Neighbours:
        """The ``k`` nearest stored vectors to ``query`` ``(D,)``.

        ``allowed`` ``(M,)`` int64 restricts the search to those ids (exactly: FAISS skips the
        others while scanning); ``exclude`` drops one id (the query clip itself) — we ask for
        one more neighbour and remove it, so it never costs a result.
        """
        q = _as_vectors(query, self.dimension)
        if q.shape[0] != 1:
            raise ValueError("search takes one query vector")
        selector = None
        available = self.size
        if allowed is not None:
            allowed = np.unique(_as_ids(allowed))  # sorted, as IDSelectorBatch needs no order
            if exclude is not None:
                allowed = allowed[allowed != exclude]
                exclude = None
            selector = faiss.IDSelectorBatch(allowed)
            available = min(available, int(allowed.size))
        wanted = min(k + (1 if exclude is not None else 0), available)
        if wanted <= 0:
            return Neighbours(np.empty(0, np.int64), np.empty(0, np.float64))
        params = None
        if selector is not None:
            params = faiss.SearchParameters()
            params.sel = selector
        with self._lock.read():
            squared, ids = self._index.search(q, wanted, params=params)
        keep = ids[0] >= 0  # FAISS pads with -1 when fewer vectors qualify
        if exclude is not None:
            keep &= ids[0] != exclude
        found = ids[0][keep][:k].astype(np.int64)
        distances = np.sqrt(np.maximum(squared[0][keep][:k].astype(np.float64), 0.0))
        return Neighbours(found, distances)

    def reconstruct(self, clip_id: int) -> np.ndarray:
        """The stored ``(D,)`` float32 vector of ``clip_id`` (``KeyError`` when absent)."""
        with self._lock.read():
            try:
                return np.asarray(self._index.reconstruct(int(clip_id)), dtype=np.float32)
            except RuntimeError:
                raise KeyError(clip_id) from None

    def replace_all(self, ids: np.ndarray, vectors: np.ndarray, *, persist: bool = True) -> None:
        """Swap in a new index holding exactly ``vectors`` ``(N, D)`` under ``ids`` ``(N,)``."""
        fresh = _empty_index(self.dimension)
        ids_ = _as_ids(ids)
        if ids_.size:
            fresh.add_with_ids(_as_vectors(vectors, self.dimension), ids_)
        with self._lock.write():
            self._index = fresh
        if persist:
            self.save()

    def save(self) -> None:
        """Write the index and its metadata atomically (temp file, then rename)."""
        # The save lock keeps two saves in order: the last state serialised is the one written.
        with self._save_lock:
            with self._lock.read():
                data = faiss.serialize_index(self._index).tobytes()
                count = int(self._index.ntotal)
            meta = {
                "descriptor": self.name,
                "version": self.version,
                "dimension": self.dimension,
                "count": count,
                "sha256": hashlib.sha256(data).hexdigest(),
            }
            self.directory.mkdir(parents=True, exist_ok=True)
            _atomic_write(self.path, data)
            _atomic_write(self.meta_path, json.dumps(meta, indent=2).encode())

    def _load_problem(self, expected_ids: np.ndarray) -> str | None:
        """Why the files on disk cannot be used (``None`` when they can; then loaded)."""
        try:
            meta = json.loads(self.meta_path.read_text())
            data = self.path.read_bytes()
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
        if meta.get("sha256") != hashlib.sha256(data).hexdigest():
            return "index file does not match its checksum"
        try:
            index = faiss.deserialize_index(np.frombuffer(data, dtype=np.uint8))
        except RuntimeError as exc:
            return f"unreadable index: {exc}"
        if not isinstance(index, faiss.IndexIDMap2) or index.d != self.dimension:
            return "index of another kind or dimension"
        ids = faiss.vector_to_array(index.id_map).astype(np.int64)
        if ids.size != index.ntotal or ids.size != meta.get("count"):
            return "index count disagrees with its metadata"
        if ids.size != expected_ids.size:
            return f"index holds {ids.size} vectors, database {expected_ids.size}"
        if not np.array_equal(np.sort(ids), np.sort(expected_ids)):
            return "index ids differ from the database"
        with self._lock.write():
            self._index = index
        return None

    def load_or_rebuild(self, expected_ids: np.ndarray, load_vectors: LoadVectors) -> str | None:
        """Load the persisted index if it holds exactly ``expected_ids`` ``(N,)``; otherwise
        rebuild it from ``load_vectors()`` and save it. Returns why it was rebuilt, or None."""
        problem = self._load_problem(_as_ids(expected_ids))
        if problem is None:
            return None
        ids, vectors = load_vectors()
        self.replace_all(ids, vectors)
        # A new, empty library has no index yet: that is no news.
        level = logging.WARNING if ids.size else logging.INFO
        log.log(
            level,
            "rebuilt the %s index from the database (%d vectors): %s",
            self.name,
            ids.size,
            problem,
        )
        return problem


class IndexSet(Mapping[str, DescriptorIndex]):
    """The indexes of every descriptor, by descriptor name."""

    def __init__(self, indexes: Mapping[str, DescriptorIndex]) -> None:
        self._indexes = dict(indexes)

    def __getitem__(self, name: str) -> DescriptorIndex:
        return self._indexes[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._indexes)

    def __len__(self) -> int:
        return len(self._indexes)

    def add(self, ids: np.ndarray | list[int], vectors: Mapping[str, np.ndarray]) -> None:
        """Add one batch: ``vectors[name]`` is ``(N, D_name)`` for the ``(N,)`` ``ids``."""
        for name, array in vectors.items():
            self._indexes[name].add(ids, array)

    def remove(self, ids: np.ndarray | list[int]) -> None:
        """Remove ``ids`` from every index."""
        for index in self._indexes.values():
            index.remove(ids)

    def sizes(self) -> dict[str, int]:
        return {name: index.size for name, index in self._indexes.items()}
