"""The measured limit: a plain dense computation of a `Count`'s size, timed on this machine in the same run.

A multiply-add count alone says nothing in milliseconds: one state's vector-matrix products run far below a
4096-state matmul's rate. So each count becomes the products themselves, on random tensors, batched as the
method would be at best (`arithmetic`: one matmul for shared weights, one batched matmul or grouped convolution
for member weights, the faster of a grouped convolution and one per member; DropConnect's per-(member, state)
weights as batched vector-matrix products), plus an MC method's mask work (a rescaled copy of the masked
elements and its random positions zeroed). The benchmark times it interleaved with the methods, so
time / limit compares like with like. Large batches are timed on a chunk of states and scaled linearly, which
keeps the limit cheap: a chunk's operands stay under `CHUNK_ELEMENTS`, past the size where batching still pays.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch as th
import torch.nn.functional as F

from paper_lib.bench.arithmetic import MEMBER_WEIGHTS, STATE_WEIGHTS, Count, Op

#: Operand elements of one timed chunk (16 MB of float32): beyond this a batch is timed in part and scaled.
CHUNK_ELEMENTS = 1 << 22


@dataclass(frozen=True)
class Limit:
    """`run()` computes `states` states' worth; the limit of a call on `n_states` is its time x `scale`."""

    run: Callable[[], object]
    states: int
    scale: float


def footprint(op: Op) -> int:
    """Operand elements one state adds to `op`: its inputs and outputs, and its own weights if per state."""
    (h, w), out = op.in_hw, math.prod(op.out_hw)
    elements = op.copies * (op.d_in * h * w + op.d_out * out)
    return elements + (op.copies * op.weights_per_copy if op.weights == STATE_WEIGHTS else 0)


def chunk_states(count: Count, n_states: int, budget: int = CHUNK_ELEMENTS) -> int:
    """States per timed chunk: all of them while every op's operands fit the budget."""
    per_state = max([footprint(op) for op in count.ops] + [2 * count.mask_elements, 1])
    return max(1, min(n_states, budget // per_state))


def _faster(candidates: list[Callable[[], object]], tries: int = 3) -> Callable[[], object]:
    """The fastest of equivalent computations (a grouped convolution is often slower than a loop on CPU)."""
    if len(candidates) == 1:
        return candidates[0]
    best, best_s = candidates[0], math.inf
    for fn in candidates:
        fn()  # warm-up
        started = time.perf_counter()
        for _ in range(tries):
            fn()
        if (seconds := time.perf_counter() - started) < best_s:
            best, best_s = fn, seconds
    return best


def _linear(op: Op, n: int, g: th.Generator) -> Callable[[], object]:
    if op.weights == STATE_WEIGHTS:  # every (copy, state) its own weights: batched vector-matrix products
        x, w = th.randn(op.copies * n, 1, op.d_in, generator=g), th.randn(op.copies * n, op.d_in, op.d_out, generator=g)
        return lambda: th.bmm(x, w)
    if op.weights == MEMBER_WEIGHTS:
        x, w = th.randn(op.copies, n, op.d_in, generator=g), th.randn(op.copies, op.d_in, op.d_out, generator=g)
        return lambda: th.bmm(x, w)
    x, w = th.randn(op.copies * n, op.d_in, generator=g), th.randn(op.d_in, op.d_out, generator=g)
    return lambda: th.mm(x, w)


def _conv(op: Op, n: int, g: th.Generator) -> Callable[[], object]:
    h, w_ = op.in_hw
    kernel = (op.d_in, op.kernel, op.kernel)
    if op.weights == STATE_WEIGHTS:  # one grouped convolution, a group per (copy, state)
        x, w = th.randn(1, op.copies * n * op.d_in, h, w_, generator=g), th.randn(op.copies * n * op.d_out, *kernel,
                                                                               generator=g)
        return lambda: F.conv2d(x, w, stride=op.stride, groups=op.copies * n)
    if op.weights == MEMBER_WEIGHTS:
        x, w = th.randn(n, op.copies * op.d_in, h, w_, generator=g), th.randn(op.copies * op.d_out, *kernel, generator=g)
        xs, ws = x.view(n, op.copies, op.d_in, h, w_).unbind(1), w.view(op.copies, op.d_out, *kernel).unbind(0)
        xs = [t.contiguous() for t in xs]
        return _faster([lambda: F.conv2d(x, w, stride=op.stride, groups=op.copies),
                        lambda: [F.conv2d(a, b, stride=op.stride) for a, b in zip(xs, ws)]])
    x, w = th.randn(op.copies * n, op.d_in, h, w_, generator=g), th.randn(op.d_out, *kernel, generator=g)
    return lambda: F.conv2d(x, w, stride=op.stride)


def _masks(count: Count, n: int, g: th.Generator) -> Callable[[], object]:
    """The mask work of n states: a rescaled copy of every masked element, its drawn positions zeroed."""
    elements, draws = count.mask_elements * n, round(count.mask_draws * n)
    source, out = th.randn(elements, generator=g), th.empty(elements)
    keep = 1.0 / (1.0 - count.drop_p)

    def run() -> th.Tensor:
        th.mul(source, keep, out=out)
        return out.index_fill_(0, th.randint(0, elements, (draws,), generator=g), 0.0)

    return run


def dense_limit(count: Count, n_states: int, budget: int = CHUNK_ELEMENTS, seed: int = 0) -> Limit:
    """The plain computation of `count` for `n_states` states (a chunk of them, scaled), ready to time."""
    n = chunk_states(count, n_states, budget)
    g = th.Generator().manual_seed(seed)
    steps = [(_conv if op.kernel else _linear)(op, n, g) for op in count.ops]
    if count.mask_elements:
        steps.append(_masks(count, n, g))

    def run() -> None:
        with th.inference_mode():
            for step in steps:
                step()

    return Limit(run, n, n_states / n)
