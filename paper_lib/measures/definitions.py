"""Uncertainty measures from the k members' outputs (paper section 3.2 and appendix D).

Pure numpy functions on member-major arrays, so each can be checked by hand:
values (k, N), action parameters (k, N, A) = logits (discrete) or action means (continuous).
Standard deviations are population std (ddof = 0), numpy's default.

`torch_measures` computes the same measures in torch, on the members' outputs where the
forward pass left them: the inference paths (`uncertainty`, `act_with_uncertainty`) then
convert only the (N,) results to numpy, not the (k, N, A) outputs. Tests hold it equal to
the numpy functions here, which stay the definition.
"""

from __future__ import annotations

import numpy as np
import torch as th
from scipy.special import softmax

MEMBER_MEASURES = ("value_std", "policy_std", "policy_js")
DISCRETE_ONLY = ("max_prob", "entropy")
#: Every measure computed from the members: the three of any action space, then the discrete-only two.
ALL_MEMBER_MEASURES = MEMBER_MEASURES + DISCRETE_ONLY


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


# --- the same measures in torch, for the batched inference paths ------------------------------
_TINY = 1e-12  # the numpy functions' clip before a log


def _torch_kl(p: th.Tensor, q: th.Tensor) -> th.Tensor:
    return (p * (p.clamp_min(_TINY).log() - q.clamp_min(_TINY).log())).sum(-1)


def _torch_policy_js(action_params: th.Tensor, discrete: bool) -> th.Tensor:
    if discrete:
        probs = th.softmax(action_params, -1)
        p, q = probs[:, None], probs[None, :]
        m = 0.5 * (p + q)
        pairwise = 0.5 * _torch_kl(p, m) + 0.5 * _torch_kl(q, m)
    else:
        pairwise = th.linalg.vector_norm(action_params[:, None] - action_params[None, :], dim=-1)
    return pairwise.amax(dim=(0, 1))


def _members_std(x: th.Tensor) -> th.Tensor:
    """Population std over the members (axis 0) as mean, deviations, mean square: two passes, as stable as
    torch's `std`, which reduces over a short leading axis ~40x slower (1.3 ms for (4, 1024, 6) here)."""
    deviations = x - x.mean(0)
    return deviations.square_().mean(0).sqrt_()


def torch_measures(values: th.Tensor | None, action_params: th.Tensor | None, discrete: bool,
                   wanted: tuple[str, ...] | None = None, exact: bool = True) -> dict[str, th.Tensor]:
    """`all_measures` in torch: each wanted measure, shape (N,), from values (k, N) and action params (k, N, A).

    `wanted` defaults to every measure that applies (member measures need k > 1; max_prob and
    entropy need discrete actions); `values` (or `action_params`) may be None when no measure
    of it is wanted. `exact` False takes the stds as `_members_std` (equal up to float rounding;
    the inference "fast" path's); True keeps the committed scores' numbers bit for bit.
    """
    std = (lambda x: x.std(0, correction=0)) if exact else _members_std
    k = (values if action_params is None else action_params).shape[0]
    if wanted is None:
        wanted = (MEMBER_MEASURES if k > 1 else ()) + (DISCRETE_ONLY if discrete else ())
    out: dict[str, th.Tensor] = {}
    probs = th.softmax(action_params, -1).mean(0) if discrete and set(wanted) & set(DISCRETE_ONLY) else None
    for name in wanted:
        if name == "value_std":
            out[name] = std(values)
        elif name == "policy_std":
            out[name] = std(action_params).mean(-1)
        elif name == "policy_js":
            out[name] = _torch_policy_js(action_params, discrete)
        elif name == "max_prob":
            out[name] = 1.0 - probs.amax(-1)
        elif name == "entropy":
            out[name] = -(probs * probs.clamp_min(_TINY).log()).sum(-1)
        else:
            raise ValueError(f"unknown measure {name!r}; use some of {MEMBER_MEASURES + DISCRETE_ONLY}")
    return out
