"""Episode detectors (DEEDEE-style running mean, DEXTER-style window forest) against hand computations."""

import math

import numpy as np
import pytest
from sklearn.ensemble import IsolationForest

from paper_lib.measures.sequences import (EpisodeMeanDetector, WindowForestDetector, causal_windows, episodes_of,
                                          sliding_windows, window_features)


def test_episode_mean_by_hand():
    # Steps 0, 2, 2, 4: mean 2, std sqrt(2). Standardized A = (-sqrt2, 0), B = (0, sqrt2);
    # running means A = (-sqrt2, -sqrt2/2), B = (0, sqrt2/2); squared distances between them 2 at t=0 and t=1,
    # so the median heuristic gives sigma^2 = 2 / 2 = 1.
    det = EpisodeMeanDetector().fit([np.array([[0.0], [2.0]]), np.array([[2.0], [4.0]])])
    assert det.sigma_ == pytest.approx(1.0)
    # A test episode (2, 2) standardizes to (0, 0), running means (0, 0).
    # t=0: distances^2 to A, B = 2, 0 -> -log((e^-1 + e^0) / 2); t=1: 0.5, 0.5 -> -log(e^-0.25) = 0.25.
    got = det.score([np.array([[2.0], [2.0]])])[0]
    np.testing.assert_allclose(got, [-math.log((math.exp(-1) + 1) / 2), 0.25])


def test_episode_mean_longer_episode_uses_last_summary_and_is_batch_invariant():
    det = EpisodeMeanDetector(sigma=1.0).fit([np.array([[0.0], [2.0]]), np.array([[2.0], [4.0]])])
    a, b = np.array([[2.0], [2.0], [2.0]]), np.array([[9.0], [0.0]])
    together = det.score([a, b])
    np.testing.assert_allclose(together[0], det.score([a])[0])
    np.testing.assert_allclose(together[1], det.score([b])[0])
    assert together[0][2] == pytest.approx(0.25)  # step 2 compares to the summary's last step (t=1)
    assert together[1][0] > together[0][0]  # far from every training start


def test_window_features_by_hand():
    f = window_features(np.array([[[0.0], [1.0], [3.0]]]))[0, 0]
    # mean 4/3, std sqrt(14/9), min 0, max 3, median 1, slope over t = -1, 0, 1: (0*-1 + 3*1) / 2, |changes| 1, 2
    np.testing.assert_allclose(f, [4 / 3, math.sqrt(14 / 9), 0, 3, 1, 1.5, 1.5])
    w = sliding_windows(np.arange(5.0)[:, None], 3)
    assert w.shape == (3, 3, 1)
    np.testing.assert_array_equal(w[-1, :, 0], [2, 3, 4])


def toy_episodes(n: int, steps: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [np.cumsum(0.1 * rng.normal(size=(steps, 2)), axis=0) for _ in range(n)]


def test_window_forest_is_isolation_forest_on_window_features():
    train = toy_episodes(3, 30, 0)
    det = WindowForestDetector(window=4, n_estimators=20, seed=7).fit(train)
    test = toy_episodes(1, 12, 1)[0]
    got = det.score([test])[0]
    assert got.shape == (12,)
    feats = window_features(sliding_windows(test, 4))
    forests = [IsolationForest(n_estimators=20, random_state=7).fit(
        np.concatenate([window_features(sliding_windows(ep, 4)) for ep in train])[:, j]) for j in range(2)]
    expected = np.mean([-forests[j].decision_function(feats[:, j]) for j in range(2)], axis=0)
    np.testing.assert_allclose(got[3:], expected)
    np.testing.assert_allclose(got[:3], expected[0])  # DEXTER: the first window's score for the first steps


def test_causal_window_forest_never_looks_ahead_and_scores_short_episodes():
    w = causal_windows(np.array([[1.0], [2.0], [3.0]]), 3)
    assert w[:, :, 0].tolist() == [[1, 1, 1], [1, 1, 2], [1, 2, 3]]  # the first state repeated in front
    train = toy_episodes(3, 30, 0)
    det = WindowForestDetector(window=4, n_estimators=20, seed=7, causal=True).fit(train)
    forests = [IsolationForest(n_estimators=20, random_state=7).fit(
        np.concatenate([window_features(causal_windows(ep, 4)) for ep in train])[:, j]) for j in range(2)]
    test = toy_episodes(1, 12, 1)[0]
    feats = window_features(causal_windows(test, 4))
    expected = np.mean([-forests[j].decision_function(feats[:, j]) for j in range(2)], axis=0)
    np.testing.assert_allclose(det.score([test])[0], expected)
    changed = test.copy()
    changed[6:] += 50.0  # a later change moves no earlier step's score
    np.testing.assert_array_equal(det.score([changed])[0][:6], det.score([test])[0][:6])
    assert det.score([test[:1]])[0].shape == (1,)  # one step is an episode too
    with pytest.raises(ValueError, match="at least 4 are needed"):
        WindowForestDetector(window=4).fit(train).score([test[:3]])  # DEXTER's own rule needs a whole window


def test_window_forest_seeded_batch_invariant_and_detects_a_jump():
    train = toy_episodes(4, 40, 0)
    a, b = toy_episodes(2, 20, 5)
    b = b.copy()
    b[10:] += 5.0  # a level shift mid-episode
    det = WindowForestDetector(window=5, n_estimators=30, seed=1).fit(train)
    together = det.score([a, b])
    again = WindowForestDetector(window=5, n_estimators=30, seed=1).fit(train).score([a, b])
    np.testing.assert_array_equal(together[1], again[1])
    np.testing.assert_array_equal(together[1], det.score([b])[0])
    assert together[1][12:].mean() > together[0][12:].mean()


def test_episodes_of_keeps_order():
    eps = episodes_of(np.arange(5.0)[:, None], np.array([3, 3, 1, 3, 1]))
    assert [e[:, 0].tolist() for e in eps] == [[0.0, 1.0, 3.0], [2.0, 4.0]]


def test_bad_input():
    with pytest.raises(ValueError, match="before fit"):
        EpisodeMeanDetector().score([np.zeros((2, 1))])
    with pytest.raises(ValueError, match="at least 2 ID episodes"):
        EpisodeMeanDetector().fit([np.zeros((3, 1))])
    with pytest.raises(ValueError, match="NaN"):
        EpisodeMeanDetector().fit([np.zeros((3, 1)), np.array([[0.0], [np.nan]])])
    with pytest.raises(ValueError, match="list of"):
        EpisodeMeanDetector().fit(np.zeros((3, 1)))
    with pytest.raises(ValueError, match=r"\(T, d\)"):
        EpisodeMeanDetector().fit([np.zeros(3), np.zeros(3)])
    det = EpisodeMeanDetector().fit([np.zeros((3, 1)), np.ones((3, 1))])
    with pytest.raises(ValueError, match="fitted number of features"):
        det.score([np.zeros((3, 2))])
    with pytest.raises(ValueError, match="sigma"):
        EpisodeMeanDetector(sigma=0.0)
    with pytest.raises(ValueError, match="at least 4"):
        WindowForestDetector(window=4).fit([np.zeros((3, 1))])
    with pytest.raises(ValueError, match="window"):
        WindowForestDetector(window=1)
    with pytest.raises(ValueError, match="before fit"):
        WindowForestDetector().score([np.zeros((20, 1))])
