"""Candidates of compressed IVF lists ranked by their exact distances.

An index of 8-bit codes (``sq8``, app/index/kinds.py) gives approximate distances: a search
asks its lists for :data:`app.index.kinds.RERANK` times the neighbours wanted and ranks them
here from the exact float32 vectors kept beside the index (app/index/frozen.py), so the
distances answered are those of a float32 scan, computed by the same FAISS kernel.

Shapes: queries ``(Q, D)`` float32; candidates ``(Q, C)`` int64 ids of the file (-1
padding); ``exact`` ``(N, D)`` float32 rows in the order of the file's sorted ids ``(N,)``.
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np


def exact_squared(query: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``(M,)`` float32 squared distances from ``query`` ``(D,)`` to ``vectors`` ``(M, D)``:
    FAISS's own kernel, the numbers an IVFFlat scan of these vectors gives."""
    vectors = np.ascontiguousarray(vectors, np.float32)
    query = np.ascontiguousarray(query, np.float32)
    distances = np.empty(vectors.shape[0], np.float32)
    if vectors.shape[0]:
        faiss.fvec_L2sqr_ny(  # type: ignore[attr-defined]
            faiss.swig_ptr(distances),
            faiss.swig_ptr(query),
            faiss.swig_ptr(vectors),
            int(vectors.shape[1]),
            int(vectors.shape[0]),
        )
    return distances


def ranked_one(
    query: np.ndarray, candidates: np.ndarray, k: int, exact: np.ndarray, sorted_ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One query's ``k`` nearest of its ``candidates`` ``(C,)`` (ids of the file, -1 padding
    last, as FAISS returns them): ``(1, k)`` exact squared distances and ids, -1 padded.

    A search by clip asks one query, and its ~20 candidates cost more in numpy calls than in
    arithmetic (each call a few microseconds): their rows are found by one binary search of
    the sorted ids (every candidate is in the file: its lists returned it). (FAISS's
    ``fvec_L2sqr_by_idx``, which reads the rows in place, starts its OpenMP threads even for
    one query: several times slower here.)"""
    found = candidates if candidates[-1] >= 0 else candidates[candidates >= 0]
    distances = exact_squared(query, np.take(exact, sorted_ids.searchsorted(found), axis=0))
    order = distances.argsort(kind="stable")[:k]
    if order.size == k:
        return distances[order].reshape(1, k), found[order].reshape(1, k)
    squared = np.full((1, k), np.inf, np.float32)
    ids = np.full((1, k), -1, np.int64)
    squared[0, : order.size] = distances[order]
    ids[0, : order.size] = found[order]
    return squared, ids


def ranked(
    queries: np.ndarray, candidates: np.ndarray, k: int, exact: np.ndarray, rows_of: Any
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest of each query's ``candidates`` ``(Q, C)`` by their exact squared
    distances: ``(Q, k)`` float32 and ids (-1 padded). ``rows_of`` maps ids ``(M,)`` to their
    rows of ``exact`` (the locator's: a batch — moments' windows — looks up thousands)."""
    count = candidates.shape[0]
    squared = np.full((count, k), np.inf, np.float32)
    ids = np.full((count, k), -1, np.int64)
    valid = candidates >= 0
    # Every candidate's row at once, gathered in one copy.
    vectors = np.ascontiguousarray(exact[rows_of(candidates[valid])], np.float32)
    ends = np.cumsum(valid.sum(axis=1))
    for row in range(count):
        first, stop = (int(ends[row - 1]) if row else 0), int(ends[row])
        if stop == first:
            continue
        distances = exact_squared(queries[row], vectors[first:stop])
        order = np.argsort(distances, kind="stable")[:k]
        squared[row, : order.size] = distances[order]
        ids[row, : order.size] = candidates[row][valid[row]][order]
    return squared, ids
