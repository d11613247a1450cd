"""The numbers behind the library map: 3-MAN features from a stored kinetic vector, PCA-2D,
isolation scores (exact over blocks, or from the random-projection forest beyond the exact
limit), modified z-scores and outliers. Pure numpy, no library (the map through the app is
tested in tests/ui/test_map.py and tests/services/test_map_geometry.py)."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.decomposition import PCA

from app.services import map_geometry
from app.services.map_geometry import (
    forest_neighbours,
    isolation_scores,
    modified_z_scores,
    pca_2d,
    robust_outliers,
    three_man_from_kinetic,
)


def test_three_man_from_kinetic_refuses_other_vectors() -> None:
    with pytest.raises(ValueError, match="50 numbers"):
        three_man_from_kinetic(np.zeros(12))
    zero = three_man_from_kinetic(np.zeros(50))
    np.testing.assert_array_equal(zero, [0.0, 0.0, 0.0])  # no motion: no energy, ratio 1


def test_pca_2d_matches_scikit_learn_up_to_sign() -> None:
    rng = np.random.default_rng(3)
    data = rng.normal(size=(200, 6)) @ rng.normal(size=(6, 6)) + 5.0
    ours = pca_2d(data)
    reference = PCA(n_components=2).fit(data)
    theirs = reference.transform(data)
    for k in range(2):
        sign = np.sign(np.dot(ours.points[:, k], theirs[:, k]))
        np.testing.assert_allclose(ours.points[:, k], sign * theirs[:, k], atol=1e-8)
    np.testing.assert_allclose(ours.explained, reference.explained_variance_ratio_, rtol=1e-8)
    # Deterministic signs: the same data gives the same map.
    np.testing.assert_array_equal(pca_2d(data).points, ours.points)
    assert pca_2d(data[:1]).points.tolist() == [[0.0, 0.0]]


def test_robust_outliers_marks_only_the_far_clip() -> None:
    rng = np.random.default_rng(4)
    cluster = rng.normal(size=(40, 5))
    far = np.full((1, 5), 20.0)
    flags = robust_outliers(np.vstack([cluster, far]))
    assert flags.tolist() == [False] * 40 + [True]
    assert not robust_outliers(cluster[:2]).any()  # too few clips to tell
    assert not robust_outliers(np.ones((10, 3))).any()  # all alike


def test_a_whole_minority_class_is_no_outlier() -> None:
    # 60 walks and 15 dashes far from them: the dashes are a class, not odd clips.
    rng = np.random.default_rng(5)
    walks = rng.normal(size=(60, 4))
    dashes = rng.normal(size=(15, 4)) + 30.0
    odd = np.array([[15.0, -15.0, 15.0, -15.0]])
    flags = robust_outliers(np.vstack([walks, dashes, odd]))
    assert flags.tolist() == [False] * 75 + [True]


def test_isolation_scores_are_exact_over_blocks() -> None:
    rng = np.random.default_rng(6)
    data = rng.normal(size=(2100, 3))  # 4e6 / 2100 -> blocks of 1904 rows: two blocks
    got = isolation_scores(data, k=3)
    pick = [0, 1, 1903, 1904, 2099]
    for i in pick:
        distances = np.sort(np.linalg.norm(data - data[i], axis=1))[1:4]
        assert got[i] == pytest.approx(distances.mean(), rel=1e-9)
    assert isolation_scores(data[:1]).tolist() == [0.0]
    assert isolation_scores(data[:2], k=5).tolist() == pytest.approx(
        [np.linalg.norm(data[0] - data[1])] * 2
    )


def test_modified_z_scores() -> None:
    values = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    median, mad = 3.0, 1.0
    np.testing.assert_allclose(modified_z_scores(values), 0.6745 * (values - median) / mad)
    flat = np.array([1.0, 1.0, 1.0, 1.0, 5.0])  # MAD 0: mean absolute deviation instead
    np.testing.assert_allclose(modified_z_scores(flat)[-1], 4.0 / (1.253314 * 0.8))
    assert modified_z_scores(np.ones(4)).tolist() == [0.0] * 4


def clustered(n: int, dimension: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.normal(scale=10.0, size=(40, dimension))
    return centres[rng.integers(0, 40, n)] + rng.normal(size=(n, dimension))


def exact_isolation(data: np.ndarray, k: int = 5) -> np.ndarray:
    """Mean distance to the k nearest others, all pairs (for comparison)."""
    squared = (data**2).sum(axis=1)
    d2 = np.maximum(squared[:, None] + squared[None, :] - 2 * data @ data.T, 0)
    np.fill_diagonal(d2, np.inf)
    return np.sqrt(np.sort(d2, axis=1)[:, :k]).mean(axis=1)


def test_the_forest_finds_nearly_every_nearest_neighbour() -> None:
    data = clustered(3000, 20, seed=1)
    far = np.random.default_rng(2).normal(scale=60.0, size=(6, 20))
    data = np.vstack([data, far])
    exact = exact_isolation(data)
    found = np.sqrt(forest_neighbours(data, 5)).mean(axis=1)
    assert np.all(found >= exact * (1 - 1e-4))  # what is missed only makes a score larger
    relative = (found - exact) / exact
    assert np.median(relative) < 0.01 and np.mean(relative < 0.05) > 0.9
    # The isolated vectors stand out either way; the flags mostly agree.
    flagged = modified_z_scores(found) > map_geometry.OUTLIER_Z
    truly = modified_z_scores(exact) > map_geometry.OUTLIER_Z
    assert flagged[-6:].all() and truly[-6:].all()
    assert (flagged & truly).sum() >= 0.8 * (flagged | truly).sum()


def test_isolation_beyond_the_exact_limit_comes_from_the_forest(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    data = clustered(600, 8, seed=3)
    monkeypatch.setattr(map_geometry, "EXACT_NEIGHBOURS_UP_TO", 500)
    scores = isolation_scores(data)
    np.testing.assert_allclose(scores, np.sqrt(forest_neighbours(data, 5)).mean(axis=1))
    assert np.median(scores / exact_isolation(data) - 1) < 0.01
