"""The evaluation metrics on small cases computed by hand."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

from app.evaluation.metrics import (
    adjusted_rand,
    contingency,
    f_measure,
    loo_1nn,
    twin_ranks,
    ward_bic_clustering,
)

# Five clips on a line: a a | b b | a, at 0, 1, 10, 11, 20.
LINE = np.array([[0.0], [1.0], [10.0], [11.0], [20.0]])
LINE_LABELS = ["a", "a", "b", "b", "a"]


class TestLoo1nn:
    def test_plain(self) -> None:
        result = loo_1nn(LINE, LINE_LABELS)
        # 0->1 a, 1->0 a, 2->3 b, 3->2 b, 4->3 b (9 < 10): four of five right.
        assert result.predicted == ["a", "a", "b", "b", "b"]
        assert result.neighbour.tolist() == [1, 0, 3, 2, 3]
        assert result.accuracy == pytest.approx(4 / 5)
        assert result.classes == ["a", "b"]
        assert result.confusion.tolist() == [[2, 1], [0, 2]]
        assert result.per_class == {"a": pytest.approx(2 / 3), "b": 1.0}
        assert result.per_class_count == {"a": 3, "b": 2}
        assert (result.scored, result.unscored, result.hopeless, result.correct) == (5, 0, 0, 4)

    def test_exclude_same_group(self) -> None:
        groups = ["g1", "g1", "g2", "g3", "g3"]
        result = loo_1nn(LINE, LINE_LABELS, exclude_same=groups)
        # 0: 1 excluded -> 2 (b); 1: 0 excluded -> 2 (b); 2 -> 3 (b);
        # 3: 4 excluded -> 2 (b); 4: 3 excluded -> 2 at distance 10 (b).
        assert result.neighbour.tolist() == [2, 2, 3, 2, 2]
        assert result.predicted == ["b", "b", "b", "b", "b"]
        assert result.accuracy == pytest.approx(2 / 5)
        assert result.confusion.tolist() == [[0, 3], [0, 2]]
        assert result.per_class == {"a": 0.0, "b": 1.0}
        assert result.hopeless == 0

    def test_hopeless_and_unscored_queries(self) -> None:
        X = np.array([[0.0], [1.0], [2.0], [3.0]])
        # Both "a" clips share group x: each has neighbours, but none of class "a".
        result = loo_1nn(X, ["a", "a", "b", "b"], exclude_same=["x", "x", "y", "z"])
        assert result.hopeless == 2
        assert result.neighbour.tolist() == [2, 2, 1, 2]
        assert result.accuracy == pytest.approx(1 / 4)
        result = loo_1nn(X, ["a", "a", "b", "b"], exclude_same=["x", "x", "y", "y"])
        # Every query's own class is its own group: all four can only be wrong.
        assert result.hopeless == 4
        assert result.accuracy == 0.0
        # Everything in one group: nobody has an allowed neighbour.
        result = loo_1nn(X, ["a", "a", "b", "b"], exclude_same=["x"] * 4)
        assert result.scored == 0 and result.unscored == 4
        assert np.isnan(result.accuracy)
        assert result.predicted == [None] * 4
        assert result.neighbour.tolist() == [-1] * 4

    def test_none_group_only_excludes_itself(self) -> None:
        result = loo_1nn(LINE, LINE_LABELS, exclude_same=[None] * 5)
        assert result.neighbour.tolist() == loo_1nn(LINE, LINE_LABELS).neighbour.tolist()

    def test_ties_go_to_the_lowest_index(self) -> None:
        X = np.array([[0.0], [-1.0], [1.0]])
        result = loo_1nn(X, ["a", "b", "c"])
        assert result.neighbour[0] == 1

    def test_precomputed_distances_and_shape_checks(self) -> None:
        D = np.abs(LINE - LINE.T)
        assert loo_1nn(LINE, LINE_LABELS, distances=D).accuracy == pytest.approx(0.8)
        with pytest.raises(ValueError):
            loo_1nn(LINE, LINE_LABELS[:4])
        with pytest.raises(ValueError):
            loo_1nn(LINE, LINE_LABELS, exclude_same=["g"] * 4)


class TestFMeasure:
    def test_contingency(self) -> None:
        M, clusters, categories = contingency(["a", "a", "a", "b", "b"], [1, 1, 2, 2, 2])
        assert clusters == [1, 2] and categories == ["a", "b"]
        assert M.tolist() == [[2, 0], [1, 2]]

    def test_two_clusters(self) -> None:
        # Cluster 1 = {a, a}, cluster 2 = {a, b, b}.  M_a = 3, M_b = 2, M = 5.
        # R_a = (2*2/3 + 1*1/3)/3 = 5/9   P_a = (2*2/2 + 1*1/3)/3 = 7/9
        # R_b = (2*2/2)/2 = 1            P_b = (2*2/3)/2 = 2/3
        # R = (3*5/9 + 2*1)/5 = 11/15    P = (3*7/9 + 2*2/3)/5 = 11/15
        f = f_measure(["a", "a", "a", "b", "b"], [1, 1, 2, 2, 2])
        assert f.recall_per_class == {"a": pytest.approx(5 / 9), "b": pytest.approx(1.0)}
        assert f.precision_per_class == {"a": pytest.approx(7 / 9), "b": pytest.approx(2 / 3)}
        assert f.recall == pytest.approx(11 / 15)
        assert f.precision == pytest.approx(11 / 15)
        assert f.f == pytest.approx(11 / 15)

    def test_one_cluster(self) -> None:
        # R_c = 1, P_c = 1/2 for both: F = 2 * 1 * 0.5 / 1.5 = 2/3.
        f = f_measure(["a", "a", "b", "b"], [7, 7, 7, 7])
        assert (f.recall, f.precision) == (pytest.approx(1.0), pytest.approx(0.5))
        assert f.f == pytest.approx(2 / 3)

    def test_singletons(self) -> None:
        # R_a = (1*1/2 + 1*1/2)/2 = 1/2, P_a = 1; R_b = P_b = 1.
        # R = (2*1/2 + 1)/3 = 2/3, P = 1, F = 2*(2/3)/(5/3) = 4/5.
        f = f_measure(["a", "a", "b"], ["x", "y", "z"])
        assert f.recall == pytest.approx(2 / 3)
        assert f.precision == pytest.approx(1.0)
        assert f.f == pytest.approx(0.8)

    def test_perfect_and_label_names_do_not_matter(self) -> None:
        f = f_measure(["walk", "walk", "run"], [2, 2, 1])
        assert (f.recall, f.precision, f.f) == (1.0, 1.0, 1.0)

    def test_adjusted_rand(self) -> None:
        assert adjusted_rand(["a", "a", "b", "b"], [5, 5, 9, 9]) == pytest.approx(1.0)
        # scikit-learn's documented example: 4/7.
        assert adjusted_rand([0, 0, 1, 1], [0, 0, 1, 2]) == pytest.approx(4 / 7)
        assert adjusted_rand([0, 0, 1, 1], [0, 0, 1, 2]) == adjusted_rand_score(
            [0, 0, 1, 1], [0, 0, 1, 2]
        )


class TestWardBic:
    def test_three_separated_blobs(self) -> None:
        rng = np.random.default_rng(0)
        centres = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0]])
        X = np.concatenate([c + rng.normal(scale=0.5, size=(15, 3)) for c in centres])
        truth = np.repeat([0, 1, 2], 15)
        result = ward_bic_clustering(X)
        assert result.k == 3
        assert adjusted_rand(truth, result.clusters) == pytest.approx(1.0)
        assert set(result.bic) <= set(range(2, 31))
        assert result.k == max(result.bic, key=lambda k: result.bic[k])
        assert result.covariance_type == "spherical"

    def test_units_do_not_change_the_choice(self) -> None:
        rng = np.random.default_rng(1)
        X = np.concatenate([rng.normal(loc=m, size=(12, 4)) for m in (0.0, 8.0, 16.0, 24.0)])
        small = ward_bic_clustering(X * 1e-3)
        large = ward_bic_clustering(X * 1e3)
        assert small.k == large.k == 4
        assert np.array_equal(small.clusters, large.clusters)

    def test_range_and_tiny_inputs(self) -> None:
        X = np.array([[0.0], [1.0], [5.0], [6.0]])
        result = ward_bic_clustering(X, k_max=3)
        assert set(result.bic) <= {2, 3}
        assert len(result.clusters) == 4
        with pytest.raises(ValueError):
            ward_bic_clustering(X[:2])
        with pytest.raises(ValueError, match="covariance_type"):
            ward_bic_clustering(X, covariance_type="banana")
        assert ward_bic_clustering(X, covariance_type="diag").covariance_type == "diag"


class TestTwinRanks:
    def test_ranks_per_format_pair(self) -> None:
        # Trial t1 in formats A and B; trial t2 in A, B and C; trial t3 only in A.
        trials = ["t1", "t1", "t2", "t2", "t2", "t3"]
        formats = ["A", "B", "A", "B", "C", "A"]
        positions = np.array([0.0, 1.0, 10.0, 12.0, 10.5, 0.5])
        D = np.abs(positions[:, None] - positions[None, :])
        pairs, nearest = twin_ranks(D, trials, formats)
        by_pair = {p.formats: p.ranks for p in pairs}
        # t1/A at 0: twin B at 1; other-trial clips nearer: t3 (0.5) -> rank 2.
        # t1/B at 1: twin A at 0; nearer: t3 (0.5) -> rank 2.
        # t2/A at 10: B at 2 -> nothing of another trial nearer -> 1; C at 0.5 -> 1.
        # t2/B at 12: A at 2 -> 1;  t2/C at 10.5: A -> 1, B -> 1.
        assert by_pair[("A", "B")] == [2, 2, 1, 1]
        assert by_pair[("A", "C")] == [1, 1]
        assert by_pair[("B", "C")] == [1, 1]
        assert nearest == [2, 2, 1, 1, 1]
        ab = next(p for p in pairs if p.formats == ("A", "B"))
        assert ab.queries == 4
        assert ab.top1 == pytest.approx(0.5)
        assert ab.median_rank == pytest.approx(1.5)
        assert ab.mean_rank == pytest.approx(1.5)

    def test_asf_amc_first(self) -> None:
        D = np.array([[0.0, 1.0], [1.0, 0.0]])
        pairs, _ = twin_ranks(D, ["t", "t"], ["bvh-mb", "asf-amc"])
        assert pairs[0].formats == ("asf-amc", "bvh-mb")

    def test_no_twins(self) -> None:
        D = np.zeros((2, 2))
        assert twin_ranks(D, ["a", "b"], ["x", "y"]) == ([], [])
