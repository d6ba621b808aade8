"""MC Dropout and MC DropConnect with masks per (member, state), as the lean inference path draws them.

The draws are exactly those of `layers.per_state_masks` (same per-state, per-layer generator
seeds, same Poisson count and positions), so outputs equal the reference modules'; the work
around them is leaner:
- one generator per thread, re-seeded per state, instead of a new generator per state and layer;
- the draws go straight into the layout the computation needs;
- DropConnect builds each state's k masked, rescaled weight copies in one reused buffer
  (a few states at a time, `PER_STATE_CHUNK_ELEMENTS`); an image shared by the members is
  convolved once per state against its k masked kernels side by side.

What stays is inherent to exact per-state DropConnect: a Bernoulli mask on every weight of
every (member, state) pair, i.e. about p * k * n_weights random positions and one masked
copy of the weights per state and layer. It cannot be folded into input or output masks.
"""

from __future__ import annotations

import math
import threading
import weakref
from dataclasses import dataclass

import numpy as np
import torch as th
import torch.nn.functional as F
from torch import nn

from paper_lib.methods.layers import (
    PER_STATE_CHUNK_ELEMENTS,
    MCDropout,
    MemberConv2d,
    MemberLinear,
    is_stochastic,
)
from paper_lib.methods.layers import _mix64 as _mix64_int

_GOLDEN = 0x9E3779B97F4A7C15  # layers._StateNoise's stream increment
_U64 = (1 << 64) - 1
#: Up to this many states, per-layer seeds are mixed as Python ints: numpy's per-call cost is higher.
_FEW_STATES = 8


def _mix64(x: np.ndarray) -> np.ndarray:
    """layers._mix64 on a uint64 array (numpy's uint64 arithmetic wraps, like the `& _U64` there)."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


_STREAMS: weakref.WeakKeyDictionary[nn.Module, dict[int, int]] = weakref.WeakKeyDictionary()


def stream_numbers(net: nn.Module) -> dict[int, int]:
    """Stream of each stochastic layer (by id), numbered in module order as `per_state_masks` does.

    Remembered per network (its layers do not change after it is built): walking the modules
    costs as much as a one-state MC Dropout layer.
    """
    streams = _STREAMS.get(net)
    if streams is None:
        streams = _STREAMS[net] = {id(m): i for i, m in enumerate(m for m in net.modules() if is_stochastic(m))}
    return streams


@dataclass
class StateSeeds:
    """One seed per state; a layer's generator seeds derive from them as `layers._StateNoise` derives them."""

    seeds: np.ndarray  # uint64, (N,)
    streams: dict[int, int]

    @classmethod
    def of(cls, net: nn.Module, state_seeds: np.ndarray | list[int]) -> StateSeeds:
        return cls(np.asarray(state_seeds, dtype=np.uint64).ravel(), stream_numbers(net))

    def for_layer(self, layer: nn.Module) -> list[int]:
        offset = (_GOLDEN * (self.streams[id(layer)] + 1)) & _U64
        if len(self.seeds) <= _FEW_STATES:
            return [_mix64_int((int(seed) + offset) & _U64) for seed in self.seeds]
        return _mix64(self.seeds + np.uint64(offset)).tolist()  # array arithmetic wraps silently

    def chunk(self, start: int, stop: int) -> StateSeeds:
        return StateSeeds(self.seeds[start:stop], self.streams)


_RATES: dict[tuple[int, float], th.Tensor] = {}
_THREAD = threading.local()


def _rate(n: int, p: float) -> th.Tensor:
    """The Poisson rate `per_state_dropped` draws the number of drops from, made once per (n, p)."""
    rate = _RATES.get((n, p))
    if rate is None:
        rate = _RATES[n, p] = th.tensor(n * -math.log1p(-p), dtype=th.float64)
    return rate


def _generator() -> th.Generator:
    """One generator per thread, re-seeded per state: manual_seed resets the whole engine, so it
    draws what a fresh generator would, without building one per state and layer."""
    generator = getattr(_THREAD, "generator", None)
    if generator is None:
        generator = _THREAD.generator = th.Generator()
    return generator


def draw_drops(seeds: list[int], n: int, p: float) -> tuple[list[th.Tensor], list[int]]:
    """Per state, the positions in [0, n) its generator drops, and how many: `per_state_dropped`'s draws."""
    generator, rate = _generator(), _rate(n, p)
    drawn, counts = [], []
    for seed in seeds:
        generator.manual_seed(seed)
        counts.append(int(th.poisson(rate, generator=generator)))
        drawn.append(th.randint(0, n, (counts[-1],), generator=generator))
    return drawn, counts


def state_major(drawn: list[th.Tensor], counts: list[int], stride: int, device: th.device) -> th.Tensor:
    """The draws as flat positions in a state-major (n_states, stride) tensor."""
    if len(counts) == 1:
        return drawn[0].to(device)
    positions = th.cat(drawn) + th.repeat_interleave(th.arange(len(counts)) * stride, th.tensor(counts))
    return positions.to(device)


def member_major(drawn: list[th.Tensor], counts: list[int], unit: int, device: th.device) -> th.Tensor:
    """The draws (member * unit + entry) as flat positions in a member-major (k, n_states, unit) tensor."""
    if len(counts) == 1:
        return drawn[0].to(device)
    n_states = len(counts)
    positions = th.cat(drawn)
    state = th.repeat_interleave(th.arange(n_states), th.tensor(counts))
    return ((positions // unit) * (n_states * unit) + state * unit + positions % unit).to(device)


def dropout(layer: MCDropout, x: th.Tensor, seeds: list[int]) -> th.Tensor:
    """(k, N, ...) with each (member, state)'s own drop mask: `per_state_dropout`'s draws and arithmetic.

    `x` may be an expanded view (a shared input): the rescaling writes the k copies.
    """
    k, unit = x.shape[0], math.prod(x.shape[2:])
    drawn, counts = draw_drops(seeds, k * unit, layer.p)
    y = (x * (1.0 / (1.0 - layer.p))).contiguous()
    y.view(-1).index_fill_(0, member_major(drawn, counts, unit, y.device), 0.0)
    return y


def _masked_weights(buffer: th.Tensor, weight: th.Tensor, seeds: list[int], p: float) -> th.Tensor:
    """buffer[:c] = c states' k rescaled weight copies (state-major), each with its own drops zeroed."""
    c = len(seeds)
    masked = buffer[:c]
    masked.copy_(weight.expand_as(masked))
    n = masked[0].numel()
    drawn, counts = draw_drops(seeds, n, p)
    return masked.view(-1).index_fill_(0, state_major(drawn, counts, n, masked.device), 0.0).view(masked.shape)


def _states_per_chunk(n_states: int, weights_per_state: int) -> int:
    return min(n_states, max(1, PER_STATE_CHUNK_ELEMENTS // weights_per_state))


def dropconnect_linear(layer: MemberLinear, x: th.Tensor, seeds: list[int]) -> th.Tensor:
    """(k, N, d_out) = (W * M) x + b with a weight mask M per (member, state), from x (k, N, d_in).

    The reference's arithmetic: rescaled weights, drops zeroed, then one row-vector-times-matrix
    product per (member, state) (the same batched mat-vec shapes, so the same numbers)."""
    k, d_out, d_in = x.shape[0], layer.d_out, layer.d_in
    weight = layer.weight.view(1, 1, d_out, d_in) * (1.0 / (1.0 - layer.p))
    n_states = len(seeds)
    chunk = _states_per_chunk(n_states, k * d_out * d_in)
    buffer = weight.new_empty(chunk, k, d_out, d_in)
    outputs = []
    for start in range(0, n_states, chunk):
        stop = min(n_states, start + chunk)
        c = stop - start
        masked = _masked_weights(buffer, weight, seeds[start:stop], layer.p)
        rows = x[:, start:stop].transpose(0, 1).reshape(c * k, 1, d_in)  # state-major, like the masks
        outputs.append(th.bmm(rows, masked.view(c * k, d_out, d_in).transpose(1, 2)).view(c, k, d_out))
    y = outputs[0] if len(outputs) == 1 else th.cat(outputs)
    return (y + layer.bias.view(1, 1, d_out)).transpose(0, 1)  # (N, k, d_out) -> member-major view


def dropconnect_conv(layer: MemberConv2d, x: th.Tensor, shared: bool, k: int, seeds: list[int]) -> th.Tensor:
    """(k, N, C', H', W'): a kernel mask per (member, state), from images (N, C, H, W) shared by the
    members (convolved once per state against its k masked kernels) or (k, N, C, H, W)."""
    c_out = layer.weight.shape[1]
    weight = layer.weight * (1.0 / (1.0 - layer.p))  # (1, C', C, kh, kw)
    n_states = len(seeds)
    chunk = _states_per_chunk(n_states, k * weight[0].numel())
    buffer = weight.new_empty(chunk, k, *weight.shape[1:])
    bias = layer.bias.view(-1).repeat(chunk * k)
    outputs = []
    for start in range(0, n_states, chunk):
        stop = min(n_states, start + chunk)
        c = stop - start
        kernels = _masked_weights(buffer, weight, seeds[start:stop], layer.p).view(c * k * c_out, *weight.shape[2:])
        if shared:
            images, groups = x[start:stop].reshape(1, -1, *x.shape[2:]), c
        else:
            images, groups = x[:, start:stop].transpose(0, 1).reshape(1, -1, *x.shape[3:]), c * k
        y = F.conv2d(images, kernels, bias[:c * k * c_out], stride=layer.stride, groups=groups)
        outputs.append(y.view(c, k, c_out, *y.shape[2:]).transpose(0, 1))
    return outputs[0] if len(outputs) == 1 else th.cat(outputs, dim=1)
