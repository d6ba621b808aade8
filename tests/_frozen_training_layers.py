"""FROZEN COPY of paper_lib/methods/layers.py as it trained the committed runs (commit 696b4c2).

Do not edit: tests/methods/test_training_numerics.py trains with these layers and with the library's,
and requires bit-identical parameters, so any change to the training path shows up there.

Member-batched layers: every tensor here is member-major, shape (k, n, ...).

Keeping the k members on a leading axis lets all of them run as one batched computation
(broadcast matmuls, batched matmuls, grouped convolutions) instead of a Python loop over k
networks. Member j of a layer only ever sees slice j of the leading axis.
"""

from __future__ import annotations

import math

import numpy as np
import torch as th
import torch.nn.functional as F
from masksembles.common import generate_masks_
from torch import nn

#: How the weights of a layer relate across members.
SHARED, ENSEMBLE, DROPCONNECT = "shared", "ensemble", "dropconnect"
WEIGHT_MODES = (SHARED, ENSEMBLE, DROPCONNECT)


def _orthogonal_(weight: th.Tensor, gain: float) -> None:
    """SB3's default init (orthogonal, gain per layer role), applied to each member's matrix."""
    if weight.dim() == 2:
        nn.init.orthogonal_(weight, gain=gain)
    else:  # (k, out, in...) -> each member initialized on its own
        for member_weight in weight:
            nn.init.orthogonal_(member_weight, gain=gain)


def init_member_weights_(weight: th.Tensor, bias: th.Tensor, fan_in: int, gain: float, ortho_init: bool) -> None:
    """Initialize a member layer exactly as SB3 initializes the matching plain layer.

    `weight` is (members, out, in...) in PyTorch's layout (a view is fine). With SB3's
    `ortho_init=True`: orthogonal with the layer role's gain, zero bias. With `ortho_init=False`
    (the rl-baselines3-zoo MuJoCo recipe): PyTorch's own `nn.Linear`/`nn.Conv2d` default,
    U(-1/sqrt(fan_in), 1/sqrt(fan_in)) for weight and bias, drawn independently per member.
    """
    if ortho_init:
        _orthogonal_(weight, gain)
        nn.init.zeros_(bias)
    else:
        bound = 1.0 / math.sqrt(fan_in)
        nn.init.uniform_(weight, -bound, bound)
        nn.init.uniform_(bias, -bound, bound)


def bernoulli_keep_mask(shape: tuple[int, ...], p: float, device: th.device) -> th.Tensor:
    """Bernoulli(1-p) keep-mask, rescaled by 1/(1-p) (inverted dropout), for weights or activations.

    A fresh mask per member per forward pass means k * n_weights Bernoulli draws, which
    dominate a DropConnect layer's cost when drawn one by one. Instead, draw M ~ Poisson(n * lam)
    positions uniformly (with replacement) and zero them, lam = -ln(1 - p): by Poisson
    splitting each weight is hit an independent Poisson(lam) number of times, so it is
    dropped independently with probability 1 - exp(-lam) = p, exactly. For p = 0.1 that is
    ~0.1 n random integers instead of n uniforms.
    """
    n = math.prod(shape)
    hits = int(th.poisson(th.tensor(n * -math.log1p(-p), dtype=th.float64)))
    mask = th.full((n,), 1.0 / (1.0 - p), device=device)
    mask[th.randint(0, n, (hits,), device=device)] = 0.0
    return mask.view(shape)


class MemberLinear(nn.Module):
    """Linear layer on (k, n, d_in) -> (k, n, d_out).

    shared:      one weight matrix for all members (Masksembles, MC Dropout), (1, d_out, d_in).
    ensemble:    k independent weight matrices, run as one batched matmul; stored (k, d_in, d_out)
                 so that bmm needs no transpose (a transposed weight's gradient would be copied
                 into place at every step).
    dropconnect: one weight matrix, but every member (sample) draws its own random weight
                 mask at every forward pass, in training and at inference (MC DropConnect).
    """

    def __init__(self, d_in: int, d_out: int, k: int, mode: str = SHARED, p: float = 0.0, gain: float = math.sqrt(2),
                 ortho_init: bool = True):
        super().__init__()
        if mode not in WEIGHT_MODES:
            raise ValueError(f"unknown weight mode {mode!r}; use one of {WEIGHT_MODES}")
        self.k, self.mode, self.p, self.d_in, self.d_out = k, mode, p, d_in, d_out
        if mode == ENSEMBLE:
            self.weight = nn.Parameter(th.empty(k, d_in, d_out))
            self.bias = nn.Parameter(th.zeros(k, 1, d_out))
            init_member_weights_(self.weight.data.transpose(1, 2), self.bias.data, d_in, gain, ortho_init)
        else:  # a leading member axis of 1, so every mode's state dict has the same rank
            self.weight = nn.Parameter(th.empty(1, d_out, d_in))
            self.bias = nn.Parameter(th.zeros(1, 1, d_out))
            init_member_weights_(self.weight.data, self.bias.data, d_in, gain, ortho_init)

    def forward(self, x: th.Tensor) -> th.Tensor:
        if self.mode == SHARED:  # .view, not [0]: indexing's backward builds and fills a full zero tensor
            return F.linear(x, self.weight.view(self.d_out, self.d_in), self.bias.view(self.d_out))
        if self.mode == ENSEMBLE:
            return th.baddbmm(self.bias, x, self.weight)
        masked = self.weight * bernoulli_keep_mask((x.shape[0], self.d_out, self.d_in), self.p, x.device)
        return th.baddbmm(self.bias, x, masked.transpose(1, 2))

    def extra_repr(self) -> str:
        return f"d_in={self.d_in}, d_out={self.d_out}, k={self.k}, mode={self.mode}, p={self.p}"


class MemberConv2d(nn.Module):
    """Conv2d on (k, n, C, H, W) -> (k, n, C', H', W'), same three weight modes as MemberLinear.

    Per-member weights run as one grouped convolution: members become channel groups.
    """

    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int, k: int, mode: str = SHARED, p: float = 0.0,
                 gain: float = math.sqrt(2), ortho_init: bool = True):
        super().__init__()
        if mode not in WEIGHT_MODES:
            raise ValueError(f"unknown weight mode {mode!r}; use one of {WEIGHT_MODES}")
        self.k, self.mode, self.p, self.stride = k, mode, p, stride
        n_weights = k if mode == ENSEMBLE else 1
        self.weight = nn.Parameter(th.empty(n_weights, c_out, c_in, kernel, kernel))
        self.bias = nn.Parameter(th.zeros(n_weights, c_out))
        init_member_weights_(self.weight.data, self.bias.data, c_in * kernel * kernel, gain, ortho_init)

    def forward(self, x: th.Tensor) -> th.Tensor:
        k, n = x.shape[:2]
        if self.mode == SHARED:
            y = F.conv2d(x.reshape(k * n, *x.shape[2:]), self.weight.squeeze(0), self.bias.squeeze(0), stride=self.stride)
            return y.view(k, n, *y.shape[1:])
        weight, bias = self.weight, self.bias
        if self.mode == DROPCONNECT:
            weight = weight * bernoulli_keep_mask((k, *weight.shape[1:]), self.p, x.device)
            bias = bias.expand(k, -1)
        grouped = x.transpose(0, 1).reshape(n, k * x.shape[2], *x.shape[3:])
        y = F.conv2d(grouped, weight.reshape(-1, *weight.shape[2:]), bias.reshape(-1), stride=self.stride, groups=k)
        return y.view(n, k, -1, *y.shape[2:]).transpose(0, 1)


class MasksemblesMask(nn.Module):
    """Fixed binary mask j on member j's slice (features on the last axis, or channels of (k,n,C,H,W)).

    The masks are a persistent buffer, so they are saved in the state dict and a reloaded
    model gives identical outputs (the reference layer keeps them non-persistent).
    """

    def __init__(self, width: int, k: int, scale: float, seed: int):
        super().__init__()
        self.register_buffer("masks", th.as_tensor(generate_masksembles_masks(width, k, scale, seed), dtype=th.float32))

    def forward(self, x: th.Tensor) -> th.Tensor:
        mask = self.masks[:, None, :]
        if x.dim() == 5:
            mask = mask[..., None, None]
        return x * mask


class MCDropout(nn.Module):
    """Dropout that stays on at inference: each of the k member copies gets independent masks."""

    def __init__(self, p: float):
        super().__init__()
        self.p = p

    def forward(self, x: th.Tensor) -> th.Tensor:
        # the same exact Bernoulli draw as DropConnect's, ~1.6x cheaper than F.dropout here
        return x * bernoulli_keep_mask(x.shape, self.p, x.device)

    def extra_repr(self) -> str:
        return f"p={self.p}"


def masksembles_kept_units(width: int, k: int, scale: float) -> int:
    """Units each mask keeps, by the reference formula."""
    return int(width / (scale * (1 - (1 - 1 / scale) ** k)))


def generate_masksembles_masks(width: int, k: int, scale: float, seed: int, max_tries: int = 10_000) -> np.ndarray:
    """The reference `masksembles.common.generation_wrapper`, bounded and seeded.

    The reference draws from numpy's global RNG and its retry loops are unbounded for some
    inputs; this runs the same steps (same draws, hence the same masks for the same global
    seed) from a private seed, restores the global RNG state, and gives up with a clear
    error instead of hanging.
    """
    validate_masksembles(width, k, scale)
    kept = masksembles_kept_units(width, k, scale)
    saved_state = np.random.get_state()
    np.random.seed(seed)
    try:
        low, high = max(scale * 0.8, 1.0), scale * 1.2
        for _ in range(1000):
            mid = (low + high) / 2
            masks = _generate_masks_bounded(kept, k, mid, max_tries)
            if masks.shape[-1] == width:
                return masks.astype(np.float32)
            if masks.shape[-1] > width:
                high = mid
            else:
                low = mid
    finally:
        np.random.set_state(saved_state)
    raise ValueError(
        f"Masksembles could not generate {k} masks of width {width} with scale {scale}; "
        "change masksembles_scale (e.g. 2.0) or the layer width"
    )


def _generate_masks_bounded(kept: int, k: int, scale: float, max_tries: int) -> np.ndarray:
    expected = int(kept * scale * (1 - (1 - 1 / scale) ** k))
    for _ in range(max_tries):
        masks = generate_masks_(kept, k, scale)
        if masks.shape[1] == expected:
            return masks
    raise ValueError(
        f"Masksembles mask generation did not converge (kept={kept}, k={k}, scale={scale:.3f}); "
        "change masksembles_scale or the layer width"
    )


def validate_masksembles(width: int, k: int, scale: float) -> None:
    """Reject what the reference generation cannot satisfy, before anything is built."""
    if not 1.0 <= scale <= 6.0:
        raise ValueError(f"masksembles_scale={scale} is outside [1, 6], the range the mask generation supports")
    if width < 10:
        raise ValueError(f"a Masksembles layer needs width >= 10, got {width}; widen the layer")
    if masksembles_kept_units(width, k, scale) < 1:
        raise ValueError(f"width {width} with k={k} and scale={scale} keeps no unit per mask; widen the layer or lower the scale")
