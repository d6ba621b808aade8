"""Each measure equals a hand computation on known member outputs."""

import numpy as np
import pytest

from paper_lib.measures import definitions as measures

VALUES = np.array([[1.0, 0.0], [3.0, 0.0], [1.0, 0.0], [3.0, 0.0]])  # (k=4, N=2)


def test_value_std_is_the_population_std_of_member_values():
    np.testing.assert_allclose(measures.value_std(VALUES), [1.0, 0.0])


def test_policy_std_averages_per_action_std():
    params = np.zeros((2, 1, 3))
    params[0, 0] = [0.0, 2.0, 4.0]
    params[1, 0] = [0.0, 0.0, 0.0]  # per-action std: 0, 1, 2 -> mean 1
    np.testing.assert_allclose(measures.policy_std(params), [1.0])


def test_max_prob_and_entropy_of_the_averaged_distribution():
    logits = np.log(np.array([[[0.9, 0.1]], [[0.5, 0.5]]]))  # averaged distribution (0.7, 0.3)
    np.testing.assert_allclose(measures.max_prob(logits), [0.3])
    np.testing.assert_allclose(measures.entropy(logits), [-(0.7 * np.log(0.7) + 0.3 * np.log(0.3))])


def test_policy_js_is_the_max_pairwise_divergence():
    p, q = np.array([1.0, 0.0]), np.array([0.0, 1.0])  # disjoint supports: JS = ln 2
    logits = np.log(np.clip(np.stack([p, p, q])[:, None, :], 1e-30, None))
    np.testing.assert_allclose(measures.policy_js(logits, discrete=True), [np.log(2)], rtol=1e-6)
    means = np.array([[[0.0, 0.0]], [[3.0, 4.0]], [[1.0, 1.0]]])
    np.testing.assert_allclose(measures.policy_js(means, discrete=False), [5.0])


def test_identical_members_give_zero_uncertainty():
    params = np.repeat(np.random.default_rng(0).normal(size=(1, 5, 3)), 4, axis=0)
    out = measures.all_measures(np.zeros((4, 5)), params, discrete=True)
    for name in ("value_std", "policy_std", "policy_js"):
        assert out[name] == pytest.approx(np.zeros(5), abs=1e-7)
