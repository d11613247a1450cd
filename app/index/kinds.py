"""The kinds of FAISS index (flat, IVF), the options that choose one, and building one.

See :mod:`app.index.descriptor_index` for what each kind trades. Shapes: batches are
``(N, D)`` float32 C-contiguous with ``(N,)`` int64 ids.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import faiss
import numpy as np

FLAT = "flat"
IVF = "ivf"
AUTO = "auto"
INDEX_TYPES = (AUTO, FLAT, IVF)
# What an IVF index's lists hold of each vector: the float32 numbers, or 8 bits per number
# (FAISS's scalar quantiser, a quarter of the bytes), the candidates then re-ranked from the
# exact vectors in a file beside the index (app/index/frozen.py).
FLOAT32 = "float32"
SQ8 = "sq8"
CODES = (FLOAT32, SQ8)
# Candidates a search of compressed lists takes per neighbour wanted, then ranks by their
# exact distances: at 100 hours of 1-s windows (1.2 M, 135-D padded to 136, nprobe 12 and
# 24) twice as many gave the same 276 nearest as the float32 lists, once as many 5 % fewer.
RERANK = 2

MIN_POINTS_PER_CELL = 39  # FAISS warns below this many training points per k-means cell
TRAIN_POINTS_PER_CELL = 64  # training sample size per cell (FAISS would take up to 256)


@dataclass(frozen=True)
class IndexOptions:
    """Which index to build (see the module docstring) and how to search it."""

    kind: str = AUTO
    auto_threshold: int = 100_000
    nlist: int = 0  # 0: 4 * sqrt(N)
    nprobe: int = 0  # 0: calibrated when the index is built (see calibrate_nprobe)
    recall_target: float = 0.995
    autosave_below: int = 20_000  # indexes this small are saved soon after a change
    save_delay: float = 1.0  # ... this many seconds after it (0: at once), changes batched
    mmap: bool = True  # IVF indexes read from their files' pages (app/index/frozen.py)
    codes: str = FLOAT32  # what IVF lists hold (see CODES)

    def __post_init__(self) -> None:
        if self.kind not in INDEX_TYPES:
            known = ", ".join(INDEX_TYPES)
            raise ValueError(f"index type must be one of {known}, not {self.kind!r}")
        if self.codes not in CODES:
            raise ValueError(f"index codes must be one of {', '.join(CODES)}, not {self.codes!r}")

    def nlist_for(self, count: int) -> int:
        """Cells of an IVF index over ``count`` vectors (0: too few vectors for IVF)."""
        wanted = self.nlist or round(4 * math.sqrt(max(count, 1)))
        return int(min(wanted, count // MIN_POINTS_PER_CELL))

    def kind_for(self, count: int, current: str | None = None) -> str:
        """The kind an index of ``count`` vectors should be, given the ``current`` kind."""
        if self.kind == FLAT:
            return FLAT
        if self.kind == IVF:
            return IVF if self.nlist_for(count) >= 1 else FLAT
        threshold = self.auto_threshold // 2 if current == IVF else self.auto_threshold
        return IVF if count >= threshold and self.nlist_for(count) >= 1 else FLAT


def as_ids(ids: np.ndarray | list[int]) -> np.ndarray:
    return np.ascontiguousarray(ids, dtype=np.int64).reshape(-1)


def as_vectors(vectors: np.ndarray, dimension: int) -> np.ndarray:
    array = np.ascontiguousarray(vectors, dtype=np.float32)
    if array.ndim == 1:
        array = array.reshape(1, -1)
    if array.ndim != 2 or array.shape[1] != dimension:
        raise ValueError(f"expected vectors of shape (N, {dimension}), got {vectors.shape}")
    if not np.isfinite(array).all():
        raise ValueError("vectors must be finite")
    return array


def padded_width(dimension: int) -> int:
    """The width an SQ8 index stores ``dimension`` numbers in: FAISS scans scalar-quantised
    codes with SIMD only at a multiple of 8 numbers (3 times slower at 135 than at 136)."""
    return -(-dimension // 8) * 8


def padded(vectors: np.ndarray, width: int) -> np.ndarray:
    """``vectors`` ``(N, D)`` float32 with zeros appended to ``width`` numbers (distances
    unchanged), C-contiguous."""
    if vectors.shape[1] == width:
        return np.ascontiguousarray(vectors, dtype=np.float32)
    out = np.zeros((vectors.shape[0], width), np.float32)
    out[:, : vectors.shape[1]] = vectors
    return out


def empty_flat(dimension: int) -> Any:
    return faiss.IndexIDMap2(faiss.IndexFlatL2(dimension))


def kind_of(index: Any) -> str | None:
    """``"flat"`` or ``"ivf"`` for the index objects this module builds, else ``None``."""
    if isinstance(index, faiss.IndexIDMap2) and isinstance(
        faiss.downcast_index(index.index), faiss.IndexFlatL2
    ):
        return FLAT
    if isinstance(index, faiss.IndexIVFFlat) and index.metric_type == faiss.METRIC_L2:
        return IVF
    if isinstance(index, faiss.IndexIVFScalarQuantizer) and index.metric_type == faiss.METRIC_L2:
        return IVF
    return None


def codes_of(index: Any) -> str:
    """What the lists of an IVF index hold (:data:`CODES`)."""
    return SQ8 if isinstance(index, faiss.IndexIVFScalarQuantizer) else FLOAT32


def build_index(
    ids: np.ndarray,
    vectors: np.ndarray,
    kind: str,
    options: IndexOptions,
    *,
    threads: int | None = None,
    seed: int = 1234,
) -> Any:
    """A new index of ``kind`` holding ``vectors`` ``(N, D)`` under ``ids`` ``(N,)``.

    IVF cells are trained with k-means on a random sample of ``64 * nlist`` vectors;
    ``threads`` lets the (one-off) training and adding use several cores. With
    ``options.codes`` SQ8 the lists hold 8-bit codes of the vectors padded to
    :func:`padded_width` (the caller keeps the exact vectors: :class:`FrozenIVF`).
    """
    dimension = int(vectors.shape[1])
    if kind != FLAT and options.codes == SQ8:  # padded a block at a time: no second copy
        dimension = padded_width(dimension)
    if kind == FLAT:
        flat = empty_flat(dimension)
        if ids.size:
            flat.add_with_ids(vectors, ids)
        return flat
    nlist = options.nlist_for(int(ids.size))
    if nlist < 1:
        raise ValueError(f"too few vectors ({ids.size}) for an IVF index")
    quantizer: Any = faiss.IndexFlatL2(dimension)
    index: Any
    if options.codes == SQ8:
        eight_bits = faiss.ScalarQuantizer.QT_8bit
        index = faiss.IndexIVFScalarQuantizer(
            quantizer, dimension, nlist, eight_bits, faiss.METRIC_L2
        )
    else:
        index = faiss.IndexIVFFlat(quantizer, dimension, nlist, faiss.METRIC_L2)
    index.own_fields = True
    quantizer.this.disown()
    index.cp.seed = seed
    rng = np.random.default_rng(seed)
    sample_size = min(int(ids.size), TRAIN_POINTS_PER_CELL * nlist)
    sample = vectors
    if sample_size < ids.size:
        sample = vectors[np.sort(rng.choice(ids.size, sample_size, replace=False))]
    before = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(threads or os.cpu_count() or 1)
    try:
        index.train(padded(sample, dimension))
        with_id_map(index)
        for start in range(0, int(ids.size), 262_144):
            stop = start + 262_144
            index.add_with_ids(padded(vectors[start:stop], dimension), ids[start:stop])
    finally:
        faiss.omp_set_num_threads(before)
    index.nprobe = options.nprobe or calibrate_nprobe(
        index, ids, vectors, target=options.recall_target, seed=seed, threads=threads
    )
    return index


def calibrate_nprobe(
    index: Any,
    ids: np.ndarray,
    vectors: np.ndarray,
    *,
    target: float,
    samples: int = 256,
    seed: int = 1234,
    threads: int | None = None,
) -> int:
    """The smallest ``nprobe`` (at most ``nlist``) whose recall@10 against exact search
    reaches ``target`` for ``samples`` stored vectors used as queries, each excluding itself
    as a search by clip does. Exact neighbours come from ``faiss.knn`` over ``vectors`` (no
    copy; the index's lists may be wider, :func:`padded_width`, the queries are padded for
    it). Found by doubling until the target is reached, then halving the gap: scanning more
    cells finds a superset of the candidates, so recall does not fall as ``nprobe`` grows.
    Every cell counts: at a million clips a search's time is mostly the cells it scans, and
    18 cells where a coarser grid offered 24 is a quarter less."""
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(ids.size, min(samples, int(ids.size)), replace=False))
    queries = np.ascontiguousarray(vectors[rows])
    before = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(threads or os.cpu_count() or 1)
    try:
        _, nearest = faiss.knn(queries, vectors, 11)
        truth = [
            set(ids[[r for r in row if r != own][:10]].tolist())
            for own, row in zip(rows, nearest, strict=True)
        ]
        total = sum(len(want) for want in truth)

        def reaches(nprobe: int) -> bool:
            params = faiss.SearchParametersIVF()
            params.nprobe = nprobe
            if codes_of(index) == SQ8:  # ranked by exact distances, as FrozenIVF searches
                _, found = _reranked(index, queries, vectors, ids, 11, params)
            else:
                _, found = index.search(padded(queries, index.d), 11, params=params)
            hits = sum(
                len(want & {int(i) for i in row if i != ids[own]})
                for own, want, row in zip(rows, truth, found, strict=True)
            )
            return hits >= target * total

        cells = int(index.nlist)
        low, high = 0, 1  # low: known short of the target (0: none yet); high: to try
        while high < cells and not reaches(high):
            low, high = high, min(2 * high, cells)
        while high - low > 1:  # the target is reached at high (or high is every cell)
            middle = (low + high) // 2
            if reaches(middle):
                high = middle
            else:
                low = middle
        return high
    finally:
        faiss.omp_set_num_threads(before)


def _reranked(
    index: Any, queries: np.ndarray, vectors: np.ndarray, ids: np.ndarray, k: int, params: Any
) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, k)`` squared distances and ids of the nearest of :data:`RERANK` times ``k``
    candidates of compressed lists, ranked by their exact distances (``vectors`` ``(N, D)``
    under ``ids`` ``(N,)``, the index's contents, unpadded)."""
    _, candidates = index.search(padded(queries, index.d), k * RERANK, params=params)
    order = np.argsort(ids, kind="stable")
    valid = candidates >= 0
    rows = order[np.searchsorted(ids, np.where(valid, candidates, ids[order[0]]), sorter=order)]
    difference = vectors[rows] - queries[:, None, :]
    squared = np.where(valid, np.einsum("qcd,qcd->qc", difference, difference), np.inf)
    ranked = np.argsort(squared, axis=1, kind="stable")[:, :k]
    found = np.take_along_axis(np.where(valid, candidates, -1), ranked, axis=1)
    return np.take_along_axis(squared, ranked, axis=1), found


def has_id_map(index: Any) -> bool:
    return bool(index.direct_map.type == faiss.DirectMap.Hashtable)  # type: ignore[attr-defined]


def with_id_map(index: Any) -> None:
    """Give an IVF index a hash table from id to position (about 40 bytes per vector), so
    :meth:`DescriptorIndex.reconstruct` finds a clip's vector at once."""
    hashtable = faiss.DirectMap.Hashtable  # type: ignore[attr-defined]
    if index.direct_map.type != hashtable:
        index.set_direct_map_type(hashtable)


def selector(index: Any, ids: np.ndarray) -> Any:
    """An id selector for ``remove_ids`` (an IVF index with an id map takes only arrays)."""
    if kind_of(index) == IVF:
        return faiss.IDSelectorArray(ids.size, faiss.swig_ptr(ids))
    return faiss.IDSelectorBatch(ids)


def ivf_ids(index: Any) -> np.ndarray:
    invlists = index.invlists
    parts = []
    for cell in range(index.nlist):
        size = invlists.list_size(cell)
        if size:
            parts.append(faiss.rev_swig_ptr(invlists.get_ids(cell), size).copy())
    return np.concatenate(parts).astype(np.int64) if parts else np.empty(0, np.int64)
