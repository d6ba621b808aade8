"""The compiled one-state computation: the members' forward passes and the continuous measures, each one numba call.

On one state every step is a small product or a few numbers, so what costs is the number of calls into the
library, not the arithmetic: torch pays a few us per operation, numpy about one, and `act_with_uncertainty` is some
forty of them. Here the whole forward pass of every member is one call and the measures another; the products
inside are BLAS calls on the same weights, so the time left is close to reading those weights once
(results/bench, `numpy_act_uncertainty_b1` against its limit). Compiled on first use and cached beside this file.
"""

from __future__ import annotations

import numba
import numpy as np

#: Activation codes of `forward` (`compiled_policy.ACTIVATION_CODES` maps the torch modules to them).
NONE, RELU, TANH = 0, 1, 2


@numba.njit(cache=True)
def _layers(h, weights, biases, activations, member):  # noqa: ANN001, ANN202 (numba types them)
    """Member `member`'s pass through stacked layers; a weight of leading size 1 is shared by every member."""
    for i, weight in enumerate(weights):
        own = member if weight.shape[0] > 1 else 0
        h = h @ weight[own] + biases[i][own]
        if activations[i] == RELU:
            h = np.maximum(h, np.float32(0.0))
        elif activations[i] == TANH:
            h = np.tanh(h)
    return h


@numba.njit(cache=True)
def forward(x, first, policy, value, split, k):  # noqa: ANN001, ANN201
    """(k, N, A) action parameters and (k, N) values of every member on x (N, d).

    `first`, `policy` and `value` are (weights, biases, activation codes): the towers' fused first layer (its
    first `split` outputs feed the policy tower), then each tower's remaining layers. State by state, so that a
    state's numbers are the same bits in any batch (one product shape, one BLAS path)."""
    n = x.shape[0]
    n_params = policy[0][len(policy[0]) - 1].shape[2]
    params = np.empty((k, n, n_params), np.float32)
    values = np.empty((k, n), np.float32)
    for s in range(n):
        state = x[s:s + 1]
        for member in range(k):
            h = _layers(state, first[0], first[1], first[2], member)
            params[member, s] = _layers(np.ascontiguousarray(h[:, :split]), policy[0], policy[1], policy[2], member)[0]
            values[member, s] = _layers(np.ascontiguousarray(h[:, split:]), value[0], value[1], value[2], member)[0, 0]
    return params, values


@numba.njit(cache=True)
def continuous_measures(params, values, low, high):  # noqa: ANN001, ANN201
    """Actions (the members' mean, clipped to [low, high]), value_std, policy_std and policy_js per state, as
    `measures.definitions` defines them (population stds; the largest distance between two members' means)."""
    k, n, n_actions = params.shape
    actions = np.empty((n, n_actions), np.float32)
    value_std, policy_std, policy_js = np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32)
    for s in range(n):
        mean = 0.0
        for j in range(k):
            mean += values[j, s]
        mean /= k
        squares = 0.0
        for j in range(k):
            squares += (values[j, s] - mean) ** 2
        value_std[s] = np.sqrt(squares / k)
        stds = 0.0
        for a in range(n_actions):
            mean = 0.0
            for j in range(k):
                mean += params[j, s, a]
            mean /= k
            actions[s, a] = min(max(mean, low[a]), high[a])
            squares = 0.0
            for j in range(k):
                squares += (params[j, s, a] - mean) ** 2
            stds += np.sqrt(squares / k)
        policy_std[s] = stds / n_actions
        largest = 0.0
        for i in range(k):
            for j in range(i + 1, k):
                distance = 0.0
                for a in range(n_actions):
                    distance += (params[i, s, a] - params[j, s, a]) ** 2
                largest = max(largest, distance)
        policy_js[s] = np.sqrt(largest)
    return actions, value_std, policy_std, policy_js
