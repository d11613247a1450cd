"""The library as the browser UI shows it: a 2-D map and a filtered list (the stick-figure
previews are in :mod:`app.services.previews`).

Map (:func:`library_map`)
    For every clip two 2-D views, both from the *stored* vectors (no clip is re-read):

    * FMDistance's 3-MAN features (Onuma et al. 2008, eq. 5) — total kinetic energy
      ``e_all``, upper/lower ratio ``r_u/l`` and limbs/trunk ratio ``r_l/t`` — computed
      from the stored ``kinetic`` vector by :func:`three_man_from_kinetic` (the vector is
      ``log1p`` of the mean energies, so ``expm1`` gives them back);
    * the first two principal components of the chosen descriptor's vectors (centred, not
      scaled: the map keeps the Euclidean geometry searches use).

    A clip is an ``outlier`` when it is isolated under the chosen descriptor: its mean
    distance to its :data:`OUTLIER_NEIGHBOURS` nearest other clips has a modified z-score
    (Iglewicz and Hoaglin: median and MAD, so the outliers do not hide themselves) above
    :data:`OUTLIER_Z`. (The distance to the library's median vector was tried first: it
    marks whole minority classes — every dash among walks — rather than odd clips.) The
    PCA and the outliers are cached by the content of the vectors they come from.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.db import browsing as browse_db
from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import vectors as vector_db
from app.motion.descriptors import kinetic
from app.services.library import Library
from app.services.lru import LRUCache

# -- map ------------------------------------------------------------------------------------

OUTLIER_Z = 3.5
"""Modified z-score of the isolation above which a clip is marked an outlier."""
OUTLIER_NEIGHBOURS = 5
"""A clip's isolation is its mean distance to this many nearest other clips."""
THREE_MAN_DESCRIPTOR = kinetic.DESCRIPTOR.name
KINETIC_DIMENSION = kinetic.DESCRIPTOR.dimension


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


def pca_2d(vectors: np.ndarray) -> Projection:
    """The first two principal components of ``(N, D)`` vectors (centred, not scaled).

    Signs are fixed (each axis's largest loading is positive) so maps do not flip between
    requests. Fewer than two dimensions or points give zeros.
    """
    data = np.asarray(vectors, dtype=np.float64)
    n = data.shape[0]
    points = np.zeros((n, 2))
    if n < 2 or data.ndim != 2 or data.shape[1] == 0:
        return Projection(points, (0.0, 0.0))
    centred = data - data.mean(axis=0)
    covariance = centred.T @ centred / (n - 1)
    values, axes = np.linalg.eigh(covariance)
    order = np.argsort(values)[::-1][:2]
    total = float(values.clip(min=0).sum())
    explained = [0.0, 0.0]
    for k, axis_index in enumerate(order):
        axis = axes[:, axis_index]
        axis = axis * (1.0 if axis[np.argmax(np.abs(axis))] >= 0 else -1.0)
        points[:, k] = centred @ axis
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
    """``(N,)`` mean Euclidean distance from each vector to its ``k`` nearest others (exact,
    in blocks of rows so 10,000 clips need ~40 MB at a time)."""
    data = np.asarray(vectors, dtype=np.float64)
    n = data.shape[0]
    k = min(k, n - 1)
    if k < 1:
        return np.zeros(n)
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


def robust_outliers(vectors: np.ndarray, threshold: float = OUTLIER_Z) -> np.ndarray:
    """``(N,)`` bool: clips far from their nearest neighbours compared with the rest — the
    modified z-score of :func:`isolation_scores` is above ``threshold``. Needs 3 clips."""
    data = np.asarray(vectors, dtype=np.float64)
    if data.shape[0] < 3:
        return np.zeros(data.shape[0], dtype=bool)
    return np.asarray(modified_z_scores(isolation_scores(data)) > threshold)


@dataclass(frozen=True)
class Layout:
    """What the map computes from one descriptor's vectors (cached by their content)."""

    projection: Projection
    outlier_scores: np.ndarray  # (N,) modified z-scores of the isolation
    outliers: np.ndarray  # (N,) bool


def vector_layout(vectors: np.ndarray) -> Layout:
    projection = pca_2d(vectors)
    n = vectors.shape[0]
    scores = modified_z_scores(isolation_scores(vectors)) if n >= 3 else np.zeros(n)
    return Layout(projection, scores, np.asarray(scores > OUTLIER_Z))


MapCache = LRUCache[tuple[str, int, str], Layout]


def new_map_cache() -> MapCache:
    return LRUCache(6)


def library_map(library: Library, descriptor: str, cache: MapCache | None = None) -> dict[str, Any]:
    """Every clip with its 3-MAN features, the PCA-2D of ``descriptor`` and an outlier flag.

    A clip without a current vector of a descriptor gets ``null`` for that view.
    """
    info = library.descriptor(descriptor)
    kinetic_info = library.descriptors.get(THREE_MAN_DESCRIPTOR)
    three_man_available = kinetic_info is not None and kinetic_info.dimension == KINETIC_DIMENSION
    with library.reads() as session:
        summaries = browse_db.clip_summaries(session)
        ids, vectors = vector_db.load_vectors(session, info.name, info.version, info.dimension)
        if three_man_available and kinetic_info is not None:
            if kinetic_info.name == info.name:
                kinetic_ids, kinetic_vectors = ids, vectors
            else:
                kinetic_ids, kinetic_vectors = vector_db.load_vectors(
                    session, kinetic_info.name, kinetic_info.version, kinetic_info.dimension
                )
        else:
            kinetic_ids, kinetic_vectors = np.zeros(0, np.int64), np.zeros((0, 0), np.float32)

    digest = hashlib.sha256(ids.tobytes() + vectors.tobytes()).hexdigest()
    key = (info.name, info.version, digest)
    layout = (
        cache.get_or_compute(key, lambda: vector_layout(vectors))
        if cache is not None
        else vector_layout(vectors)
    )
    projection = layout.projection
    # Round whole arrays once; per-clip work is then dictionary look-ups only.
    id_list = ids.tolist()
    pca_by_id = dict(zip(id_list, np.round(projection.points, 5).tolist(), strict=True))
    outlier_by_id = dict(zip(id_list, layout.outliers.tolist(), strict=True))
    score_by_id = dict(zip(id_list, np.round(layout.outlier_scores, 2).tolist(), strict=True))
    three_man_by_id: dict[int, list[float]] = {}
    if len(kinetic_ids):
        features = three_man_many(kinetic_vectors)
        finite = np.all(np.isfinite(features), axis=1)
        three_man_by_id = dict(
            zip(
                kinetic_ids[finite].tolist(),
                np.round(features[finite], 5).tolist(),
                strict=True,
            )
        )

    clips = []
    for summary in summaries:
        clip_id = summary.id
        man = three_man_by_id.get(clip_id)
        clips.append(
            {
                "id": clip_id,
                "name": summary.name,
                "labels": list(summary.labels),
                "format": summary.format,
                "duration": round(float(summary.duration), 3),
                "frame_count": summary.frame_count,
                "x": None if man is None else man[0],
                "y": None if man is None else man[1],
                "three_man": man,
                "pca": pca_by_id.get(clip_id),
                "outlier": outlier_by_id.get(clip_id, False),
                "outlier_score": score_by_id.get(clip_id),
            }
        )
    return {
        "descriptor": info.name,
        "count": len(clips),
        "three_man_available": three_man_available,
        "three_man_axes": ["e_all", "r_u/l", "r_l/t"],
        "pca_explained_variance": [round(v, 4) for v in projection.explained],
        "outlier_rule": (
            f"isolation = mean {info.name} distance to the {OUTLIER_NEIGHBOURS} nearest other "
            f"clips; outlier when its modified z-score (median/MAD) is over {OUTLIER_Z}"
        ),
        "clips": clips,
    }


# -- filtered list --------------------------------------------------------------------------


def find_clips(
    library: Library, *, q: str | None, label: label_db.LabelFilter, limit: int, offset: int
) -> tuple[list[clip_db.ClipRecord], int]:
    """One page (id order) of the clips whose name contains ``q`` (case-insensitive) and
    that carry every label of ``label``; and how many match in total."""
    with library.reads() as session:
        page_ids, total = browse_db.find_clip_ids(
            session, name_contains=q, label=label, limit=limit, offset=offset
        )
        found = clip_db.get_clips(session, page_ids)
    return [found[i] for i in page_ids if i in found], total


def label_counts(library: Library) -> list[tuple[str, int]]:
    """Every label in use with its number of clips, most used first."""
    with library.reads() as session:
        return browse_db.label_counts(session)
