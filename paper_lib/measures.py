"""Uncertainty measures from the k members' outputs (paper section 3.2 and appendix D).

Pure numpy functions on member-major arrays, so each can be checked by hand:
values (k, N), action parameters (k, N, A) = logits (discrete) or action means (continuous).
Standard deviations are population std (ddof = 0), numpy's default.
"""

from __future__ import annotations

import numpy as np
from scipy.special import softmax

MEMBER_MEASURES = ("value_std", "policy_std", "policy_js")
DISCRETE_ONLY = ("max_prob", "entropy")


def value_std(values: np.ndarray) -> np.ndarray:
    """Std of the k values: value uncertainty."""
    return values.std(axis=0)


def policy_std(action_params: np.ndarray) -> np.ndarray:
    """Mean over actions (or action dims) of the std of the k logits (or means): policy uncertainty."""
    return action_params.std(axis=0).mean(axis=-1)


def averaged_probs(logits: np.ndarray) -> np.ndarray:
    return softmax(logits, axis=-1).mean(axis=0)


def max_prob(logits: np.ndarray) -> np.ndarray:
    """1 - max probability of the members' averaged distribution."""
    return 1.0 - averaged_probs(logits).max(axis=-1)


def entropy(logits: np.ndarray) -> np.ndarray:
    """Entropy (nats) of the members' averaged distribution."""
    p = averaged_probs(logits)
    return -(p * np.log(np.clip(p, 1e-12, None))).sum(axis=-1)


def policy_js(action_params: np.ndarray, discrete: bool) -> np.ndarray:
    """Max pairwise Jensen-Shannon divergence (discrete) or L2 distance of means (continuous).

    All k x k pairs at once; the diagonal is 0 and the matrix symmetric, so its max is the
    max over distinct pairs.
    """
    if discrete:
        probs = softmax(action_params, axis=-1)
        p, q = probs[:, None], probs[None, :]
        m = 0.5 * (p + q)
        pairwise = 0.5 * _kl(p, m) + 0.5 * _kl(q, m)
    else:
        pairwise = np.linalg.norm(action_params[:, None] - action_params[None, :], axis=-1)
    return pairwise.max(axis=(0, 1))


def _kl(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    p_safe, q_safe = np.clip(p, 1e-12, None), np.clip(q, 1e-12, None)
    return (p * (np.log(p_safe) - np.log(q_safe))).sum(axis=-1)


def all_measures(values: np.ndarray, action_params: np.ndarray, discrete: bool) -> dict[str, np.ndarray]:
    out = {"value_std": value_std(values), "policy_std": policy_std(action_params),
           "policy_js": policy_js(action_params, discrete)}
    if discrete:
        out.update(max_prob=max_prob(action_params), entropy=entropy(action_params))
    return out
