"""The numbers behind the library map (:mod:`app.services.library_map`), pure numpy: FMDistance's
3-MAN features from stored ``kinetic`` vectors, a 2-D principal-component projection, and how
isolated each vector is among its nearest neighbours (modified z-scores, outliers).

The work grows as N log N, not N²: beyond :data:`EXACT_NEIGHBOURS_UP_TO` vectors the nearest
neighbours come from a random-projection forest (:func:`forest_neighbours`), and the PCA axes
are fitted on a sample of :data:`PCA_SAMPLE` vectors; bench/bench_map.py measures it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from app.motion.descriptors import kinetic

OUTLIER_Z = 3.5
"""Modified z-score of the isolation above which a clip is marked an outlier."""
OUTLIER_NEIGHBOURS = 5
"""A clip's isolation is its mean distance to this many nearest other clips."""
KINETIC_DIMENSION = kinetic.DESCRIPTOR.dimension
EXACT_NEIGHBOURS_UP_TO = 5_000
"""Up to this many clips the nearest neighbours are exact (a block of all pairs: under a
second); beyond, a random-projection forest finds them (:func:`forest_neighbours`)."""
FOREST_TREES = 8
FOREST_LEAF = 64
PCA_SAMPLE = 20_000
"""The PCA axes are fitted on at most this many clips (drawn at random, the same each time);
every clip is then projected on them."""


def three_man_from_kinetic(vector: np.ndarray) -> np.ndarray:
    """FMDistance's 3-MAN features ``(3,)`` — e_all, r_u/l, r_l/t (paper eq. 5) — from a
    stored ``kinetic`` vector (``log1p`` of the mean energy per joint DOF, then 2 root terms).

    Equals :func:`app.motion.descriptors.kinetic.three_man` of the clip's body up to the
    float32 rounding of the stored vector.
    """
    values = np.asarray(vector, dtype=np.float64).reshape(-1)
    if values.size != KINETIC_DIMENSION:
        raise ValueError(f"a kinetic vector has {KINETIC_DIMENSION} numbers, got {values.size}")
    return np.asarray(three_man_many(values[None, :])[0])


def three_man_many(vectors: np.ndarray) -> np.ndarray:
    """:func:`three_man_from_kinetic` of each row of ``(N, 50)`` -> ``(N, 3)``."""
    values = np.asarray(vectors, dtype=np.float64).reshape(-1, KINETIC_DIMENSION)
    return kinetic.three_man_from_vectors(values)


@dataclass(frozen=True)
class Projection:
    points: np.ndarray  # (N, 2)
    explained: tuple[float, float]  # fraction of the total variance along each axis


def pca_2d(vectors: np.ndarray, *, sample: int = PCA_SAMPLE) -> Projection:
    """The first two principal components of ``(N, D)`` vectors (centred, not scaled), the
    axes fitted on at most ``sample`` of them (drawn with a fixed seed), every one projected.

    Signs are fixed (each axis's largest loading is positive) so maps do not flip between
    requests. Fewer than two dimensions or points give zeros.
    """
    data = np.asarray(vectors, dtype=np.float64)
    n = data.shape[0]
    points = np.zeros((n, 2))
    if n < 2 or data.ndim != 2 or data.shape[1] == 0:
        return Projection(points, (0.0, 0.0))
    fitted = data if n <= sample else data[np.random.default_rng(0).choice(n, sample, False)]
    mean = fitted.mean(axis=0)
    centred = fitted - mean
    covariance = centred.T @ centred / (len(fitted) - 1)
    values, axes = np.linalg.eigh(covariance)
    order = np.argsort(values)[::-1][:2]
    total = float(values.clip(min=0).sum())
    explained = [0.0, 0.0]
    for k, axis_index in enumerate(order):
        axis = axes[:, axis_index]
        axis = axis * (1.0 if axis[np.argmax(np.abs(axis))] >= 0 else -1.0)
        points[:, k] = (data - mean) @ axis
        explained[k] = max(float(values[axis_index]), 0.0) / total if total > 0 else 0.0
    return Projection(points, (explained[0], explained[1]))


def modified_z_scores(values: np.ndarray) -> np.ndarray:
    """Iglewicz and Hoaglin's modified z-scores ``0.6745 (x - median) / MAD`` of ``(N,)``
    values; when the MAD is 0, ``(x - median) / (1.253314 * mean absolute deviation)``;
    all zeros when every value is the same."""
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        return np.zeros(0)
    centre = np.median(x)
    deviation = np.abs(x - centre)
    mad = float(np.median(deviation))
    if mad > 0:
        return np.asarray(0.6745 * (x - centre) / mad)
    mean_ad = float(deviation.mean())
    if mean_ad == 0:
        return np.zeros_like(x)
    return np.asarray((x - centre) / (1.253314 * mean_ad))


def isolation_scores(vectors: np.ndarray, k: int = OUTLIER_NEIGHBOURS) -> np.ndarray:
    """``(N,)`` mean Euclidean distance from each vector to its ``k`` nearest others: exact
    up to :data:`EXACT_NEIGHBOURS_UP_TO` vectors (in blocks of rows so 10,000 clips need
    ~40 MB at a time), from :func:`forest_neighbours` beyond (the nearest found, so never
    below the exact score)."""
    data = np.asarray(vectors, dtype=np.float64)
    n = data.shape[0]
    k = min(k, n - 1)
    if k < 1:
        return np.zeros(n)
    if n > EXACT_NEIGHBOURS_UP_TO:
        return np.asarray(np.sqrt(forest_neighbours(data, k)).mean(axis=1))
    squared = np.einsum("ij,ij->i", data, data)
    scores = np.empty(n)
    block = max(1, min(n, 4_000_000 // max(n, 1)))
    for start in range(0, n, block):
        rows = slice(start, min(n, start + block))
        d2 = squared[rows, None] + squared[None, :] - 2.0 * (data[rows] @ data.T)
        np.maximum(d2, 0.0, out=d2)
        d2[np.arange(d2.shape[0]), np.arange(start, rows.stop)] = np.inf  # not itself
        nearest = np.partition(d2, k - 1, axis=1)[:, :k]
        scores[rows] = np.sqrt(nearest).mean(axis=1)
    return scores


def forest_neighbours(
    vectors: np.ndarray,
    k: int,
    *,
    trees: int = FOREST_TREES,
    leaf: int = FOREST_LEAF,
    seed: int = 0,
) -> np.ndarray:
    """``(N, k)`` squared distances from each of ``(N, D)`` vectors to the ``k`` nearest
    others found by a random-projection forest, ascending. Each tree halves the vectors at
    the median of their projection on a random direction (one per level), again and again
    down to leaves of at most ``leaf``, and compares all pairs within each leaf; a vector's
    neighbours are the nearest it met in any tree. O(trees N (log N + leaf) D) instead of
    O(N^2 D): near neighbours mostly share a leaf, and what is missed makes a score larger,
    never smaller (``inf`` when a vector met fewer than ``k`` others)."""
    data = np.ascontiguousarray(vectors, dtype=np.float32)
    n = data.shape[0]
    rng = np.random.default_rng(seed)
    found: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for _ in range(trees):
        for rows in _forest_leaves(data, leaf, rng):
            found.append(_nearest_in_leaves(data, rows, k))
    result = np.full((n, k), np.inf)
    if not found:
        return result
    row = np.concatenate([f[0] for f in found])
    other = np.concatenate([f[1] for f in found])
    d2 = np.concatenate([f[2] for f in found]).astype(np.float64)
    # The same pair met in several trees counts once; then each vector's nearest, in order.
    _, first = np.unique(row.astype(np.int64) * n + other, return_index=True)
    row, d2 = row[first], d2[first]
    order = np.lexsort((d2, row))
    row, d2 = row[order], d2[order]
    starts = np.searchsorted(row, np.arange(n))
    rank = np.arange(len(row)) - starts[row]
    within = rank < k
    result[row[within], rank[within]] = d2[within]
    return result


def _forest_leaves(data: np.ndarray, leaf: int, rng: np.random.Generator) -> Iterator[np.ndarray]:
    """The leaves of one random-projection tree over ``data`` ``(N, D)``, as ``(L, m)`` row
    indices (every leaf of ``m`` rows; one array per leaf size). Level by level: a stable
    sort by (node, projection on the level's direction) puts each node's lower half first."""
    n = data.shape[0]
    levels = max(0, int(np.ceil(np.log2(max(n, 1) / leaf))))
    projected = data @ rng.standard_normal((data.shape[1], levels)).astype(np.float32)
    order = np.arange(n)
    bounds = np.array([0, n])
    for level in range(levels):
        sizes = np.diff(bounds)
        node = np.repeat(np.arange(len(sizes)), sizes)
        order = order[np.lexsort((projected[order, level], node))]
        bounds = np.sort(np.concatenate([bounds, bounds[:-1] + sizes // 2]))
    sizes = np.diff(bounds)
    for size in np.unique(sizes):
        if size < 2:
            continue
        starts = bounds[:-1][sizes == size]
        yield order[starts[:, None] + np.arange(size)]


def _nearest_in_leaves(
    data: np.ndarray, leaves: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For ``(L, m)`` leaves of rows of ``data``: each row's nearest ``min(k, m - 1)`` others
    of its leaf as (rows, others, squared distances), flat."""
    count = min(k, leaves.shape[1] - 1)
    members = data[leaves]  # (L, m, D) float32: the neighbours' order, not their last digits
    squared = np.einsum("lmd,lmd->lm", members, members)
    d2 = squared[:, :, None] + squared[:, None, :] - 2.0 * (members @ members.transpose(0, 2, 1))
    np.maximum(d2, 0.0, out=d2)
    d2[:, np.arange(leaves.shape[1]), np.arange(leaves.shape[1])] = np.inf
    nearest = np.argpartition(d2, count - 1, axis=2)[:, :, :count]
    rows = np.repeat(leaves.reshape(-1), count)
    others = np.take_along_axis(leaves[:, None, :], nearest, axis=2).reshape(-1)
    return rows, others, np.take_along_axis(d2, nearest, axis=2).reshape(-1)


def robust_outliers(vectors: np.ndarray, threshold: float = OUTLIER_Z) -> np.ndarray:
    """``(N,)`` bool: clips far from their nearest neighbours compared with the rest — the
    modified z-score of :func:`isolation_scores` is above ``threshold``. Needs 3 clips."""
    data = np.asarray(vectors, dtype=np.float64)
    if data.shape[0] < 3:
        return np.zeros(data.shape[0], dtype=bool)
    return np.asarray(modified_z_scores(isolation_scores(data)) > threshold)
