"""The compiled one-state computation: every member's forward pass and the continuous measures in one numba call.

On one state every step is a small product or a few numbers, so what costs is the number of calls into a library,
not the arithmetic: torch pays a few us per operation, numpy about one, and `act_with_uncertainty` is some forty of
them. Here the whole computation is one call over weights packed in one array (`Program`), each layer a loop that
reads its weight rows once and skips the rows of inputs that are zero (after a ReLU about half of them), so the time
left is close to reading the weights (results/bench, `compiled_act_uncertainty_b1` against its limit). Compiled on
first use and cached beside this file.
"""

from __future__ import annotations

import numba
import numpy as np

#: Activation codes of a layer's row in a `Program` table.
NONE, RELU, TANH = 0, 1, 2
#: Columns of a `Program` table row: where a layer's weights (members x d_out x d_in) and biases (members x d_out)
#: start in the packed array, its members (1: shared by all), its sizes and its activation.
WEIGHTS, BIASES, MEMBERS, D_IN, D_OUT, ACTIVATION = range(6)


#: tanh(x) = x p(x^2) / q(x^2) on [-CLAMP, CLAMP], +-1 beyond in float32: Eigen's float tanh (`generic_fast_tanh_float`,
#: within a few float32 ulps of the exact value, tests/deploy). libm's scalar tanhf, the only tanh numba has here,
#: took half of a one-state pass; this runs in vector lanes.
_TANH_CLAMP = 7.90531110763549805
_TANH_P = (-2.76076847742355e-16, 2.00018790482477e-13, -8.60467152213735e-11, 5.12229709037114e-08,
           1.48572235717979e-05, 6.37261928875436e-04, 4.89352455891786e-03)
_TANH_Q = (1.19825839466702e-06, 1.18534705686654e-04, 2.26843463243900e-03, 4.89352518554385e-03)


@numba.njit(cache=True, fastmath={"contract"})
def tanh(x):  # noqa: ANN001, ANN201
    """float32 tanh as a rational function (see _TANH_P)."""
    if abs(x) < np.float32(0.0004):
        return x
    x = min(max(x, np.float32(-_TANH_CLAMP)), np.float32(_TANH_CLAMP))
    x2 = x * x
    p = np.float32(_TANH_P[0])
    for coefficient in _TANH_P[1:]:
        p = p * x2 + np.float32(coefficient)
    q = np.float32(_TANH_Q[0])
    for coefficient in _TANH_Q[1:]:
        q = q * x2 + np.float32(coefficient)
    return x * p / q


@numba.njit(cache=True, fastmath={"reassoc", "contract"})
def _layer(h, packed, row, member):  # noqa: ANN001, ANN202 (numba types them)
    """One member's output of one layer on one state: bias + W h, activated. Each output is one dot product over
    a contiguous weight row (weights stored output-major); reassociating its sum lets it run in vector lanes."""
    own = member if row[MEMBERS] > 1 else 0
    d_in, d_out = row[D_IN], row[D_OUT]
    weights = row[WEIGHTS] + own * d_in * d_out
    biases = row[BIASES] + own * d_out
    matrix = packed[weights:weights + d_in * d_out].reshape((d_out, d_in))
    out = np.empty(d_out, np.float32)
    for o in range(d_out):
        weight_row = matrix[o]
        total = np.float32(0.0)
        for i in range(d_in):
            total += h[i] * weight_row[i]
        total += packed[biases + o]
        if row[ACTIVATION] == RELU:
            total = max(total, np.float32(0.0))
        elif row[ACTIVATION] == TANH:
            total = tanh(total)
        out[o] = total
    return out


@numba.njit(cache=True)
def forward(x, packed, table, n_policy_layers, split, k):  # noqa: ANN001, ANN201
    """(k, N, A) action parameters and (k, N) values of every member on x (N, d), state by state (a state's bits
    do not depend on its batch). `table` row 0 is the towers' fused first layer (its first `split` outputs feed
    the policy tower), then the policy tower's other `n_policy_layers` layers, then the value tower's."""
    n = x.shape[0]
    n_params = table[n_policy_layers, D_OUT]
    params = np.empty((k, n, n_params), np.float32)
    values = np.empty((k, n), np.float32)
    for s in range(n):
        for member in range(k):
            first = _layer(x[s], packed, table[0], member)
            h = first[:split]
            for layer in range(1, n_policy_layers + 1):
                h = _layer(h, packed, table[layer], member)
            params[member, s] = h
            h = first[split:]
            for layer in range(n_policy_layers + 1, table.shape[0]):
                h = _layer(h, packed, table[layer], member)
            values[member, s] = h[0]
    return params, values


@numba.njit(cache=True)
def act_continuous(x, packed, table, n_policy_layers, split, k, low, high):  # noqa: ANN001, ANN201
    """Actions (the members' mean, clipped to [low, high]), value_std, policy_std and policy_js per state, as
    `measures.definitions` defines them (population stds; the largest distance between two members' means)."""
    params, values = forward(x, packed, table, n_policy_layers, split, k)
    _, n, n_actions = params.shape
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
