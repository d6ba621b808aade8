"""Feature-space detectors against hand computations."""

import numpy as np
import pytest

from paper_lib.measures.detectors import KNNDetector, MahalanobisDetector, split_fit_eval
from paper_lib.scoring.metrics import detection_metrics

# Four corners of a square: mean (1, 1), per-feature std 1 (ddof=0), zero correlation,
# so after standardization the covariance is the identity and Mahalanobis = Euclidean.
SQUARE = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])


def test_mahalanobis_exact_on_square():
    det = MahalanobisDetector(covariance="empirical").fit(SQUARE)
    np.testing.assert_allclose(det.score(np.array([[1.0, 1.0], [3.0, 1.0], [4.0, 5.0]])), [0.0, 2.0, 5.0])


def test_mahalanobis_matches_formula_with_correlation():
    X = np.array([[0.0, 0.0], [1.0, 2.0], [2.0, 3.0], [3.0, 7.0], [4.0, 6.0], [5.0, 11.0]])
    q = np.array([[2.5, 5.0], [0.0, 8.0]])
    mu, sd = X.mean(0), X.std(0)  # StandardScaler uses the population std
    Z, Zq = (X - mu) / sd, (q - mu) / sd
    S = Z.T @ Z / len(Z)  # MLE covariance of the standardized data
    expected = np.sqrt(np.einsum("ij,jk,ik->i", Zq, np.linalg.inv(S), Zq))
    got = MahalanobisDetector(covariance="empirical").fit(X).score(q)
    np.testing.assert_allclose(got, expected)
    # The anti-correlated point (0, 8) lies off the data's diagonal: it must score higher.
    assert got[1] > got[0]


def test_knn_exact_distances():
    X = np.array([[0.0], [1.0], [2.0], [3.0]])  # mean 1.5, std sqrt(1.25)
    s = np.sqrt(1.25)
    kth = KNNDetector(k=2).fit(X).score(np.array([[10.0], [1.5]]))
    np.testing.assert_allclose(kth, [8 / s, 0.5 / s])  # 2nd-nearest of 10 is 2; of 1.5 is 1 or 2
    mean = KNNDetector(k=2, aggregate="mean").fit(X).score(np.array([[10.0]]))
    np.testing.assert_allclose(mean, [(7 + 8) / 2 / s])


@pytest.mark.parametrize("det", [MahalanobisDetector(), MahalanobisDetector("empirical"), KNNDetector(k=5)])
def test_far_points_score_higher(det):
    rng = np.random.default_rng(0)
    fit, id_eval = rng.normal(size=(400, 5)), rng.normal(size=(200, 5))
    ood = rng.normal(loc=4.0, size=(200, 5))
    det.fit(fit)
    m = detection_metrics(det.score(id_eval), det.score(ood))
    assert m["auroc"] > 0.99
    near_far = det.score(np.array([[0.0] * 5, [1.0] * 5, [3.0] * 5]))
    assert near_far[0] < near_far[1] < near_far[2]


def test_image_states_are_flattened():
    rng = np.random.default_rng(1)
    imgs = rng.normal(size=(30, 2, 3, 3))
    q = rng.normal(size=(4, 2, 3, 3))
    a = KNNDetector(k=3).fit(imgs).score(q)
    b = KNNDetector(k=3).fit(imgs.reshape(30, -1)).score(q.reshape(4, -1))
    np.testing.assert_allclose(a, b)


def test_detector_errors():
    with pytest.raises(ValueError, match="before fit"):
        KNNDetector().score(SQUARE)
    with pytest.raises(ValueError, match="needs at least 5"):
        KNNDetector(k=5).fit(SQUARE)
    with pytest.raises(ValueError, match="needs at least 3"):
        MahalanobisDetector("empirical").fit(SQUARE[:2])
    with pytest.raises(ValueError, match="3 features but was fit on 2"):
        MahalanobisDetector().fit(SQUARE).score(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="one row per state"):
        KNNDetector(k=1).fit(np.arange(4.0))
    with pytest.raises(ValueError, match="NaN"):
        KNNDetector(k=1).fit(np.array([[0.0], [np.nan]]))
    with pytest.raises(ValueError, match="covariance"):
        MahalanobisDetector("robust")


def test_split_fit_eval_partitions_and_is_seeded():
    states = np.zeros((11, 3))
    fit_idx, eval_idx = split_fit_eval(states, np.random.default_rng(0), fit_fraction=0.5)
    assert len(fit_idx) == 6 and len(eval_idx) == 5  # round(5.5) = 6
    assert np.intersect1d(fit_idx, eval_idx).size == 0
    np.testing.assert_array_equal(np.sort(np.concatenate([fit_idx, eval_idx])), np.arange(11))
    assert np.all(np.diff(fit_idx) > 0) and np.all(np.diff(eval_idx) > 0)
    again = split_fit_eval(11, np.random.default_rng(0), fit_fraction=0.5)
    np.testing.assert_array_equal(again[0], fit_idx)
    other = split_fit_eval(11, np.random.default_rng(1), fit_fraction=0.5)
    assert not np.array_equal(other[0], fit_idx)


def test_split_fit_eval_errors():
    with pytest.raises(ValueError, match="fit_fraction"):
        split_fit_eval(10, np.random.default_rng(0), fit_fraction=1.0)
    with pytest.raises(ValueError, match="empty fit or eval"):
        split_fit_eval(1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="numpy Generator"):
        split_fit_eval(10, 0)


def test_split_by_episodes_keeps_whole_episodes_on_one_side():
    episodes = np.repeat(np.arange(10), [5, 3, 8, 4, 6, 5, 5, 2, 7, 5])
    fit_idx, eval_idx = split_fit_eval(len(episodes), np.random.default_rng(0), groups=episodes)
    assert np.intersect1d(fit_idx, eval_idx).size == 0
    np.testing.assert_array_equal(np.sort(np.concatenate([fit_idx, eval_idx])), np.arange(len(episodes)))
    assert np.intersect1d(episodes[fit_idx], episodes[eval_idx]).size == 0, "no episode on both sides"
    assert len(np.unique(episodes[fit_idx])) == 5
    with pytest.raises(ValueError, match="at least 2"):
        split_fit_eval(5, np.random.default_rng(0), groups=np.zeros(5))
    with pytest.raises(ValueError, match="one label per state"):
        split_fit_eval(5, np.random.default_rng(0), groups=np.zeros(4))
