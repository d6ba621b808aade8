"""PEDM's dynamics-model detector: its score by hand, its bounds, seeding, batch invariance, bad input."""

import math

import numpy as np
import pytest
import torch

from paper_lib.measures.dynamics import PEDMConfig, PEDMDetector, ProbEnsemble, pedm_score

TINY = PEDMConfig(ens_size=2, hidden=(8,), decays=(1e-4, 1e-4), epochs=3, batch_size=16, n_particles=10)


def transitions(n_episodes: int = 4, steps: int = 20, seed: int = 0):
    """A linear toy system s' = s + 0.1 a + noise: 2 state dims, 1 action dim."""
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(n_episodes * steps, 2))
    a = rng.uniform(-1, 1, size=(n_episodes * steps, 1))
    s2 = s + 0.1 * a + 0.01 * rng.normal(size=s.shape)
    return s, a, s2, np.repeat(np.arange(n_episodes), steps)


def test_score_by_hand_two_states_one_dim():
    # One member with mean 0.5 and var 4 (std 2), two particles eps = -1, +1: samples -1.5 and 2.5.
    mean, var, eps = np.full((1, 2, 1), 0.5), np.full((1, 2, 1), 4.0), np.array([[[-1.0], [1.0]]])
    target = np.array([[1.0], [-1.5]])
    # state 1: (-1.5 - 1)^2 = 6.25, (2.5 - 1)^2 = 2.25 -> 2.25; state 2: 0 and 16 -> 0.
    np.testing.assert_allclose(pedm_score(mean, var, target, eps), [2.25, 0.0])


def test_score_is_min_over_members_of_mean_over_dims():
    mean = np.array([[[0.0, 0.0]], [[1.0, 3.0]]])  # member 0 predicts (0, 0), member 1 (1, 3), no spread
    var = np.zeros_like(mean)
    eps = np.zeros((2, 1, 2))
    # target (1, 1): member 0 -> (1 + 1) / 2 = 1; member 1 -> (0 + 4) / 2 = 2; min = 1
    np.testing.assert_allclose(pedm_score(mean, var, np.array([[1.0, 1.0]]), eps), [1.0])


def test_logvar_soft_bounds_by_hand():
    model = ProbEnsemble(1, 1, PEDMConfig(ens_size=1, hidden=(2,), decays=(0.0, 0.0)), np.random.default_rng(0))
    with torch.no_grad():
        for w in model.weights:
            w.zero_()
        model.biases[-1].copy_(torch.tensor([[[0.3, 0.0]]]))  # mean 0.3, raw logvar 0
        mean, logvar = model(torch.zeros(1, 1, 1))
    softplus = lambda x: math.log1p(math.exp(x))  # noqa: E731
    upper = 0.5 - softplus(0.5 - 0.0)
    expected = -10.0 + softplus(upper + 10.0)
    assert mean.item() == pytest.approx(0.3)
    assert logvar.item() == pytest.approx(expected, abs=1e-6)


def test_fitted_score_matches_definition_and_standardization():
    s, a, s2, ep = transitions()
    det = PEDMDetector(TINY, seed=0).fit(s, a, s2, ep)
    mean, var, target = det.member_gaussians(s[:5], a[:5], s2[:5])
    # The target is the standardized delta with the training states' statistics.
    np.testing.assert_allclose(target, (s2[:5] - s[:5]) / det.obs_sigma_, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(det.score(s[:5], a[:5], s2[:5]), pedm_score(mean, var, target, det.eps_), rtol=1e-6)
    assert det.eps_.shape == (2, 5, 2)  # 10 particles, 5 per member, one draw per state dim


def test_seeded_and_batch_invariant():
    s, a, s2, ep = transitions()
    one = PEDMDetector(TINY, seed=3).fit(s, a, s2, ep)
    two = PEDMDetector(TINY, seed=3).fit(s, a, s2, ep)
    full = one.score(s, a, s2)
    np.testing.assert_array_equal(full, two.score(s, a, s2))
    singles = np.concatenate([one.score(s[i:i + 1], a[i:i + 1], s2[i:i + 1]) for i in range(len(s))])
    np.testing.assert_allclose(singles, full, rtol=1e-5)
    rev = one.score(s[::-1], a[::-1], s2[::-1], chunk=7)[::-1]
    np.testing.assert_allclose(rev, full, rtol=1e-5)
    other = PEDMDetector(TINY, seed=4).fit(s, a, s2, ep).score(s, a, s2)
    assert not np.allclose(other, full)


def test_surprising_next_state_scores_higher():
    s, a, s2, ep = transitions(n_episodes=6, steps=40)
    det = PEDMDetector(PEDMConfig(ens_size=2, hidden=(16,), decays=(1e-4, 1e-4), epochs=30, batch_size=32,
                                  n_particles=10), seed=0).fit(s, a, s2, ep)
    id_scores = det.score(s, a, s2)
    ood_scores = det.score(s, a, s2 + 1.0)  # every next state pushed off its dynamics
    assert np.median(ood_scores) > 2 * np.median(id_scores)
    assert (ood_scores > np.median(id_scores)).all()


def test_bad_input():
    s, a, s2, ep = transitions()
    det = PEDMDetector(TINY)
    with pytest.raises(ValueError, match="before fit"):
        det.score(s, a, s2)
    bad = s.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        det.fit(bad, a, s2, ep)
    with pytest.raises(ValueError, match="one row per transition"):
        det.fit(s, a[:-1], s2, ep)
    with pytest.raises(ValueError, match="same shape"):
        det.fit(s, a, s2[:, :1], ep)
    with pytest.raises(ValueError, match="2-D"):
        det.fit(s[:, 0], a, s2, ep)
    with pytest.raises(ValueError, match="one id per transition"):
        det.fit(s, a, s2, ep[:-1])
    with pytest.raises(ValueError, match="episode"):
        det.fit(s[:20], a[:20], s2[:20], ep[:20])  # one episode: none left to hold out
    det.fit(s, a, s2, ep)
    with pytest.raises(ValueError, match="same env"):
        det.score(s, np.hstack([a, a]), s2)
    with pytest.raises(ValueError, match="multiple of ens_size"):
        PEDMConfig(ens_size=3, n_particles=10)
    with pytest.raises(ValueError, match="one entry per layer"):
        PEDMConfig(hidden=(8,), decays=(1e-4,))
