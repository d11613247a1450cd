"""Scores of a descriptor against labels, following Miura et al. (2013), section 4.

* :func:`loo_1nn` — supervised: leave-one-out 1-nearest-neighbour classification under the
  Euclidean distance; its overall accuracy is the paper's empirical accuracy ``A_e``.
  ``exclude_same`` forbids neighbours sharing a group value with the query (same style, same
  trial in another format ...), so a descriptor cannot score by recognising near-duplicates.
* :func:`ward_bic_clustering` — unsupervised: Ward's hierarchical clustering, cut at the
  number of clusters that maximises the Bayesian information criterion of a Gaussian mixture
  with that many components.
* :func:`f_measure` — the paper's eq. 4, and :func:`adjusted_rand` (sklearn's ARI).
* :func:`twin_ranks` — where a clip's twin (the same trial in another file format) ranks
  among its neighbours.

Everything here is pure numpy / scipy / scikit-learn on arrays; nothing reads files.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import cdist
from sklearn.exceptions import ConvergenceWarning
from sklearn.metrics import adjusted_rand_score
from sklearn.mixture import GaussianMixture

from app.evaluation import COVARIANCE_TYPES, DEFAULT_COVARIANCE

# ----------------------------------------------------------------------------- supervised


@dataclass(frozen=True)
class LooResult:
    """Leave-one-out 1-NN classification.

    Attributes
    ----------
    accuracy:
        Correct / scored queries (Miura's ``A_e``); ``nan`` when nothing was scored.
    classes:
        Sorted distinct labels; the order of ``confusion``'s rows and columns.
    confusion:
        ``(C, C)`` counts, rows the true label, columns the predicted one (scored queries).
    per_class:
        Label -> accuracy over the scored queries of that label (``nan`` if none).
    per_class_count:
        Label -> number of scored queries of that label.
    predicted:
        Per query, the label of its nearest allowed neighbour, ``None`` when it had none.
    neighbour:
        Per query, the index of that neighbour, ``-1`` when it had none.
    scored:
        Queries with at least one allowed neighbour.
    unscored:
        Queries with no allowed neighbour (left out of every number above).
    hopeless:
        Scored queries none of whose allowed neighbours carries their label, so they cannot
        be right (e.g. a class of one, or a class all in the query's excluded group).
    """

    accuracy: float
    classes: list[str]
    confusion: np.ndarray
    per_class: dict[str, float]
    per_class_count: dict[str, int]
    predicted: list[str | None]
    neighbour: np.ndarray
    scored: int
    unscored: int
    hopeless: int

    @property
    def correct(self) -> int:
        return int(np.trace(self.confusion))


def pairwise_distances(X: np.ndarray) -> np.ndarray:
    """``(n, n)`` Euclidean distances between the rows of ``X`` (float64)."""
    X = np.asarray(X, dtype=np.float64)
    return cdist(X, X)


def _allowed(n: int, exclude_same: Sequence[object] | np.ndarray | None) -> np.ndarray:
    """``(n, n)`` bool: may row ``j`` be the neighbour of query ``i``."""
    allowed = ~np.eye(n, dtype=bool)
    if exclude_same is not None:
        groups = np.asarray(exclude_same, dtype=object)
        if groups.shape != (n,):
            raise ValueError(f"exclude_same has shape {groups.shape}, expected ({n},)")
        # Queries without a group value (None) are only kept from matching themselves.
        known = np.array([g is not None for g in groups])
        same = (groups[:, None] == groups[None, :]) & known[:, None] & known[None, :]
        allowed &= ~same
    return allowed


def loo_1nn(
    X: np.ndarray,
    labels: Sequence[str],
    exclude_same: Sequence[object] | np.ndarray | None = None,
    *,
    distances: np.ndarray | None = None,
) -> LooResult:
    """Leave-one-out 1-nearest-neighbour classification under the Euclidean distance.

    Parameters
    ----------
    X:
        ``(n, d)`` one row per clip.
    labels:
        ``n`` labels.
    exclude_same:
        Optional ``n`` group values: a candidate with the query's group value is never its
        neighbour (``None`` = no group). The query itself never is.
    distances:
        Precomputed :func:`pairwise_distances` of ``X`` (to share between calls).

    Ties between equally near candidates go to the lowest index, so results are
    deterministic.
    """
    labels = [str(label) for label in labels]
    n = len(labels)
    D = pairwise_distances(X) if distances is None else np.asarray(distances, dtype=np.float64)
    if D.shape != (n, n):
        raise ValueError(f"{D.shape[0]} vectors but {n} labels")
    allowed = _allowed(n, exclude_same)
    masked = np.where(allowed, D, np.inf)
    has_candidate = np.asarray(allowed.any(axis=1), dtype=bool)
    neighbour = np.where(has_candidate, np.argmin(masked, axis=1) if n else 0, -1)

    classes = sorted(set(labels))
    index = {label: i for i, label in enumerate(classes)}
    label_ids = np.array([index[label] for label in labels], dtype=int)
    confusion = np.zeros((len(classes), len(classes)), dtype=int)
    predicted: list[str | None] = []
    hopeless = 0
    for i in range(n):
        if not has_candidate[i]:
            predicted.append(None)
            continue
        j = int(neighbour[i])
        predicted.append(labels[j])
        confusion[label_ids[i], label_ids[j]] += 1
        if not np.any(allowed[i] & (label_ids == label_ids[i])):
            hopeless += 1
    scored = int(has_candidate.sum())
    per_class_count = {c: int(confusion[k].sum()) for k, c in enumerate(classes)}
    per_class = {
        c: (float(confusion[k, k] / per_class_count[c]) if per_class_count[c] else float("nan"))
        for k, c in enumerate(classes)
    }
    accuracy = float(np.trace(confusion) / scored) if scored else float("nan")
    return LooResult(
        accuracy=accuracy,
        classes=classes,
        confusion=confusion,
        per_class=per_class,
        per_class_count=per_class_count,
        predicted=predicted,
        neighbour=neighbour.astype(int),
        scored=scored,
        unscored=n - scored,
        hopeless=hopeless,
    )


# --------------------------------------------------------------------------- unsupervised


@dataclass(frozen=True)
class FMeasure:
    """Miura et al. eq. 4: recall ``R``, precision ``P`` and ``F = 2RP/(R+P)``.

    ``recall_per_class`` / ``precision_per_class`` are the paper's ``R_c`` / ``P_c``.
    """

    f: float
    recall: float
    precision: float
    recall_per_class: dict[str, float]
    precision_per_class: dict[str, float]


def contingency(
    true: Sequence[object] | np.ndarray, clusters: Sequence[object] | np.ndarray
) -> tuple[np.ndarray, list, list]:
    """``M[q, c]``: samples of category ``c`` in cluster ``q``, with sorted cluster and category
    values."""
    if len(true) != len(clusters):
        raise ValueError(f"{len(true)} labels but {len(clusters)} cluster ids")
    categories = sorted(set(true), key=str)
    cluster_ids = sorted(set(clusters), key=str)
    c_index = {c: i for i, c in enumerate(categories)}
    q_index = {q: i for i, q in enumerate(cluster_ids)}
    M = np.zeros((len(cluster_ids), len(categories)), dtype=np.int64)
    for c, q in zip(true, clusters, strict=True):
        M[q_index[q], c_index[c]] += 1
    return M, cluster_ids, categories


def f_measure(
    true: Sequence[object] | np.ndarray, clusters: Sequence[object] | np.ndarray
) -> FMeasure:
    """F-measure of a clustering against ground-truth categories, exactly Miura et al. eq. 4.

    With ``M`` samples, ``M_c`` of category ``c`` and ``M_{q,c}`` of category ``c`` in
    cluster ``q``::

        R_{q,c} = M_{q,c} / M_c              P_{q,c} = M_{q,c} / sum_c' M_{q,c'}
        R_c = sum_q M_{q,c} R_{q,c} / M_c    P_c = sum_q M_{q,c} P_{q,c} / M_c
        R = sum_c M_c R_c / M                P = sum_c M_c P_c / M
        F = 2 R P / (R + P)
    """
    M_qc, _, categories = contingency(true, clusters)
    if M_qc.size == 0:
        raise ValueError("f_measure of an empty set")
    M_qc = M_qc.astype(np.float64)
    M_c = M_qc.sum(axis=0)  # per category
    cluster_size = M_qc.sum(axis=1)  # per cluster
    M = M_qc.sum()
    R_qc = M_qc / M_c[None, :]
    P_qc = M_qc / cluster_size[:, None]
    R_c = (M_qc * R_qc).sum(axis=0) / M_c
    P_c = (M_qc * P_qc).sum(axis=0) / M_c
    R = float((M_c * R_c).sum() / M)
    P = float((M_c * P_c).sum() / M)
    F = 2 * R * P / (R + P) if R + P > 0 else 0.0
    return FMeasure(
        f=float(F),
        recall=R,
        precision=P,
        recall_per_class={str(c): float(v) for c, v in zip(categories, R_c, strict=True)},
        precision_per_class={str(c): float(v) for c, v in zip(categories, P_c, strict=True)},
    )


def adjusted_rand(
    true: Sequence[object] | np.ndarray, clusters: Sequence[object] | np.ndarray
) -> float:
    """Adjusted Rand index (scikit-learn), 1 for identical partitions, ~0 for chance."""
    return float(adjusted_rand_score([str(t) for t in true], [str(c) for c in clusters]))


@dataclass(frozen=True)
class ClusteringResult:
    """Ward's clustering cut at the BIC-best number of clusters.

    Attributes
    ----------
    k:
        Chosen number of clusters.
    clusters:
        ``(n,)`` cluster id per sample, ``1..k``.
    bic:
        Number of clusters tried -> BIC in the paper's "larger is better" convention
        (``2 log L - p log n``, i.e. minus scikit-learn's ``GaussianMixture.bic``).
    covariance_type:
        The Gaussian mixture's covariance model.
    """

    k: int
    clusters: np.ndarray
    bic: dict[int, float]
    covariance_type: str


DEFAULT_MAX_CLUSTERS = 30


def ward_bic_clustering(
    X: np.ndarray,
    *,
    k_min: int = 2,
    k_max: int | None = None,
    covariance_type: str = DEFAULT_COVARIANCE,
    random_state: int = 0,
) -> ClusteringResult:
    """Ward's hierarchical clustering with the number of clusters chosen by the BIC.

    For each ``k`` in ``k_min..k_max`` (default ``min(30, n - 1)``) the Ward tree
    (``scipy.cluster.hierarchy.linkage(X, "ward")``) is cut into ``k`` clusters, a
    scikit-learn ``GaussianMixture`` with ``k`` components is fitted starting from those
    clusters' means, and its BIC is recorded in the paper's convention ``2 log L - p log n``
    (*larger* is better; scikit-learn's ``bic()`` is the negative of it, smaller is better).
    The cut with the largest BIC is returned.

    ``covariance_type`` is the mixture's covariance model; the default ``"spherical"`` (one
    variance per component) is the model Ward's criterion itself assumes and keeps the
    parameter count low enough for the few dozen to few hundred clips of an evaluation set
    (a ``"full"`` covariance per component needs far more samples than dimensions x clusters).
    ``X`` is divided by its overall spread first, which leaves the Ward tree unchanged but
    keeps the mixture's fixed covariance regularisation (1e-6) negligible for any units.
    """
    if covariance_type not in COVARIANCE_TYPES:
        raise ValueError(f"covariance_type must be one of {COVARIANCE_TYPES}")
    X = np.asarray(X, dtype=np.float64)
    n = X.shape[0]
    if n < 3:
        raise ValueError(f"clustering needs at least 3 samples, got {n}")
    spread = float(np.sqrt(((X - X.mean(axis=0)) ** 2).sum(axis=1).mean()))
    scaled = X / spread if spread > 0 else X
    tree = linkage(scaled, method="ward")
    upper = min(DEFAULT_MAX_CLUSTERS if k_max is None else k_max, n - 1)
    lower = max(1, min(k_min, upper))
    bic: dict[int, float] = {}
    cuts: dict[int, np.ndarray] = {}
    for k in range(lower, upper + 1):
        clusters = fcluster(tree, t=k, criterion="maxclust")
        found = int(clusters.max())
        if found != k:  # ties in the tree can make some k unreachable
            continue
        cuts[k] = clusters
        means = np.stack([scaled[clusters == q].mean(axis=0) for q in range(1, k + 1)])
        mixture = GaussianMixture(
            n_components=k,
            covariance_type=covariance_type,
            means_init=means,
            random_state=random_state,
            max_iter=200,
        )
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                mixture.fit(scaled)
                value = -float(mixture.bic(scaled))
        except (ValueError, np.linalg.LinAlgError):
            continue
        if np.isfinite(value):
            bic[k] = value
    if not bic:
        k = lower
        clusters = fcluster(tree, t=k, criterion="maxclust")
        return ClusteringResult(k, clusters, {}, covariance_type)
    best = max(bic, key=lambda kk: (bic[kk], -kk))
    return ClusteringResult(best, cuts[best], bic, covariance_type)


# ----------------------------------------------------------------------------- twins


@dataclass(frozen=True)
class TwinPairScore:
    """How format twins find each other, for one pair of formats (queries from both sides).

    ``ranks`` holds, per query clip of either format that has a twin in the other, the rank
    of that twin among the clips of *other* trials by distance to the query (1 = the twin is
    nearer than every clip of another trial, i.e. the nearest neighbour once the query's
    other twins are set aside).
    """

    formats: tuple[str, str]
    ranks: list[int]

    @property
    def queries(self) -> int:
        return len(self.ranks)

    @property
    def top1(self) -> float:
        return float(np.mean(np.array(self.ranks) == 1)) if self.ranks else float("nan")

    @property
    def median_rank(self) -> float:
        return float(np.median(self.ranks)) if self.ranks else float("nan")

    @property
    def mean_rank(self) -> float:
        return float(np.mean(self.ranks)) if self.ranks else float("nan")


def format_order(name: str) -> tuple[int, str]:
    """Sort key putting the original ``asf-amc`` first, then the others alphabetically."""
    return (0 if name == "asf-amc" else 1, name)


def twin_ranks(
    distances: np.ndarray, trials: Sequence[str], formats: Sequence[str]
) -> tuple[list[TwinPairScore], list[int]]:
    """Ranks of format twins: clips with the same trial value and a different format.

    Parameters
    ----------
    distances:
        ``(n, n)`` pairwise distances of all clips (every clip is a candidate).
    trials, formats:
        Per clip its trial (the file stem) and its format.

    Returns
    -------
    pairs:
        One :class:`TwinPairScore` per pair of formats sharing at least one trial, ordered
        with ``asf-amc`` first. The rank of twin ``j`` for query ``i`` is
        ``1 + #{m : trial[m] != trial[i], D[i, m] < D[i, j]}``: clips of the query's own
        trial (its other twins) do not push a twin down.
    nearest:
        Per clip that has a twin in any other format, the rank of its nearest twin (the
        smallest of its pair ranks): 1 when its nearest neighbour is one of its twins.
    """
    D = np.asarray(distances, dtype=np.float64)
    trial_array = np.asarray(trials, dtype=object)
    format_array = np.asarray(formats, dtype=object)
    ranks: dict[tuple[str, str], list[int]] = {
        (a, b): [] for a, b in combinations(sorted(set(formats), key=format_order), 2)
    }
    nearest: list[int] = []
    for i in range(len(trials)):
        same_trial = trial_array == trial_array[i]
        twins = np.flatnonzero(same_trial & (format_array != format_array[i]))
        if twins.size == 0:
            continue
        others = D[i, ~same_trial]
        best: int | None = None
        for j in twins:
            rank = 1 + int(np.sum(others < D[i, j]))
            a, b = sorted((str(formats[i]), str(formats[int(j)])), key=format_order)
            ranks[(a, b)].append(rank)
            best = rank if best is None else min(best, rank)
        assert best is not None
        nearest.append(best)
    pairs = [TwinPairScore(pair, r) for pair, r in ranks.items() if r]
    return pairs, nearest
