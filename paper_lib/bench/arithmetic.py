"""The arithmetic each method needs, counted from the network's shapes: the floor of the limit column.

Issue 70 asks for every benchmark timing against what its arithmetic allows, not against hand-set targets. This
module turns a built policy into the list of dense products one state needs (`Op`), and their multiply-adds
(MACs), for the part of the network a measurement needs: the policy network (`predict`), or the policy and
value networks (`act_uncertainty`, `uncertainty`: value_std needs the values). How each method is counted, at
best (the least an exact computation of the method's outputs must do):

- Plain PPO: each layer once (the Nature CNN's trunk once for both heads, as SB3 shares it).
- A layer whose input is the same for every member and whose weights are shared (the first layer of every
  member method but the Ensemble; the Nature CNN's conv1) runs once, on the units any member keeps: its outputs
  are the same for all members until a member-specific layer.
- Masksembles: after a mask, member j computes only its kept units, from its kept inputs (the kept counts read
  from the network's actual masks; the reference generation keeps equally many per member): k products of
  kept_in x kept_out.
- MC Dropout: k samples of the full network from the first dropout on (dense: a dropped unit still costs its
  product in a dense kernel), plus the dropout masks' elements (k x units per dropout layer).
- MC DropConnect: k samples of the full network from the first masked layer on; a masked layer's weights differ
  per (member, state), so it is k x states vector-matrix products, and its masks have k x n_weights elements per
  state (about -ln(1 - p) x that many random positions drawn: `layers.bernoulli_keep_mask`).
- Ensemble: k full networks, the first layer included (own weights).
- Convolutions: c_out x c_in x kernel area x output positions per image.

Activations, bias adds, the measures themselves and Python overhead are not counted: the limit is a floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from torch import nn

from paper_lib.methods.layers import DROPCONNECT, ENSEMBLE, MasksemblesMask, MCDropout, MemberConv2d, MemberLinear
from paper_lib.methods.networks import MemberMLP, MemberNatureCNN

#: How an op's weights relate to its rows (what the best batching of it is).
SHARED_WEIGHTS = "shared"      # one weight set for all rows: one matmul / convolution of copies x states rows
MEMBER_WEIGHTS = "members"     # one weight set per copy (member): one batched matmul / grouped convolution
STATE_WEIGHTS = "per_state"    # one weight set per (copy, state): DropConnect's exact per-state masks


@dataclass(frozen=True)
class Op:
    """One dense product per state: `copies` rows (members) of `d_in` -> `d_out`, weights related by `weights`.

    A convolution (`kernel` > 0) maps c_in = d_in channels of an `in_hw` image to c_out = d_out channels.
    """

    copies: int
    d_in: int
    d_out: int
    weights: str = SHARED_WEIGHTS
    kernel: int = 0
    stride: int = 1
    in_hw: tuple[int, int] = (1, 1)

    @property
    def out_hw(self) -> tuple[int, int]:
        if not self.kernel:
            return (1, 1)
        return tuple((s - self.kernel) // self.stride + 1 for s in self.in_hw)  # type: ignore[return-value]

    @property
    def weights_per_copy(self) -> int:
        return self.d_out * self.d_in * max(1, self.kernel) ** 2

    @property
    def macs(self) -> int:
        """Multiply-adds per state."""
        return self.copies * self.weights_per_copy * math.prod(self.out_hw)


@dataclass(frozen=True)
class Count:
    """What one state needs: its dense products and the mask elements an MC method draws per state."""

    ops: tuple[Op, ...]
    mask_elements: int = 0
    drop_p: float = 0.0

    @property
    def macs(self) -> int:
        return sum(op.macs for op in self.ops)

    @property
    def mask_draws(self) -> float:
        """Expected random positions drawn per state (Poisson splitting: -ln(1 - p) per masked element)."""
        return self.mask_elements * -math.log1p(-self.drop_p) if self.drop_p else 0.0

    def __add__(self, other: Count) -> Count:
        return Count(self.ops + other.ops, self.mask_elements + other.mask_elements,
                     max(self.drop_p, other.drop_p))


def kept_counts(mask: MasksemblesMask) -> tuple[int, int]:
    """(units each member keeps, units any member keeps) of a Masksembles mask, from its actual masks."""
    masks = mask.masks
    per_member = masks.sum(1)
    if bool((per_member != per_member[0]).any()):
        raise ValueError("Masksembles masks with unequal kept counts: this count assumes the reference's equal ones")
    return int(per_member[0]), int((masks.sum(0) > 0).sum())


class _Walker:
    """Walks layers in order, tracking whether activations already differ per member and their kept units."""

    def __init__(self, k: int, hw: tuple[int, int] = (1, 1)):
        self.k, self.hw = k, hw
        self.per_member = False  # activations differ per member from here on
        self.kept: int | None = None  # units (channels) each member holds, when a mask cut them
        self.ops: list[Op] = []
        self.mask_elements = 0
        self.drop_p = 0.0

    def layer(self, layer: MemberLinear | MemberConv2d, mask_after: MasksemblesMask | None) -> None:
        conv = isinstance(layer, MemberConv2d)
        if conv:
            c_out, c_in, kernel = (int(s) for s in layer.weight.shape[1:4])
            shape = dict(kernel=kernel, stride=layer.stride, in_hw=self.hw)
        else:
            c_out, c_in, shape = layer.d_out, layer.d_in, {}
        d_in = self.kept if self.kept is not None else c_in
        if layer.mode == ENSEMBLE:
            op = Op(self.k, d_in, c_out, MEMBER_WEIGHTS, **shape)
        elif layer.mode == DROPCONNECT:
            op = Op(self.k, d_in, c_out, STATE_WEIGHTS, **shape)
            self.mask_elements += op.copies * op.weights_per_copy
            self.drop_p = layer.p
        elif not self.per_member:  # shared input, shared weights: once, on the units any member keeps
            op = Op(1, d_in, kept_counts(mask_after)[1] if mask_after is not None else c_out, **shape)
        elif mask_after is not None or self.kept is not None:  # Masksembles: each member's kept units
            out = kept_counts(mask_after)[0] if mask_after is not None else c_out
            op = Op(self.k, d_in, out, MEMBER_WEIGHTS, **shape)
        else:
            op = Op(self.k, d_in, c_out, SHARED_WEIGHTS, **shape)
        self.ops.append(op)
        self.hw = op.out_hw
        self.per_member = self.per_member or op.copies > 1
        self.kept = None

    def stochastic(self, module: nn.Module, width: int) -> None:
        if isinstance(module, MasksemblesMask):
            self.per_member, self.kept = True, kept_counts(module)[0]
        elif isinstance(module, MCDropout):
            self.per_member = True
            self.mask_elements += self.k * width * math.prod(self.hw)
            self.drop_p = module.p

    def flatten(self) -> None:
        """Conv activations become a vector: the next layer's d_in already counts every position."""
        self.hw = (1, 1)

    def count(self) -> Count:
        return Count(tuple(self.ops), self.mask_elements, self.drop_p)


def _tower(modules: nn.Sequential, k: int) -> Count:
    walker = _Walker(k)
    layers = list(modules)
    for i, module in enumerate(layers):
        if isinstance(module, MemberLinear):
            after = next((m for m in layers[i + 1:i + 3] if isinstance(m, MasksemblesMask)), None)
            walker.layer(module, after)
        elif isinstance(module, (MasksemblesMask, MCDropout)):
            width = next(m.d_out for m in reversed(layers[:i]) if isinstance(m, MemberLinear))
            walker.stochastic(module, width)
    return walker.count()


def _mask_of(module: nn.Module) -> MasksemblesMask | None:
    return module if isinstance(module, MasksemblesMask) else None


def _member_cnn(net: MemberNatureCNN, obs_hw: tuple[int, int], actor: bool, critic: bool) -> Count:
    walker = _Walker(net.k, obs_hw)
    walker.layer(net.conv1, _mask_of(net.after_conv1))
    walker.stochastic(net.after_conv1, int(net.conv1.weight.shape[1]))
    walker.layer(net.conv2, None)
    walker.layer(net.conv3, None)
    walker.flatten()
    walker.layer(net.fc, _mask_of(net.after_fc))
    walker.stochastic(net.after_fc, net.fc.d_out)
    trunk_state = (walker.per_member, walker.kept)
    for head, wanted in ((net.policy_head, actor), (net.value_head, critic)):
        if wanted:
            walker.per_member, walker.kept = trunk_state
            walker.layer(head, None)
    return walker.count()


def _plain(modules: list[nn.Module], hw: tuple[int, int]) -> Count:
    """Plain torch layers (SB3's), each once."""
    ops = []
    for module in modules:
        if isinstance(module, nn.Conv2d):
            ops.append(Op(1, module.in_channels, module.out_channels, kernel=module.kernel_size[0],
                          stride=module.stride[0], in_hw=hw))
            hw = ops[-1].out_hw
        elif isinstance(module, nn.Linear):
            ops.append(Op(1, module.in_features, module.out_features))
    return Count(tuple(ops))


def _image_hw(policy) -> tuple[int, int]:
    shape = policy.observation_space.shape
    return (int(shape[-2]), int(shape[-1])) if len(shape) == 3 else (1, 1)


def network_count(policy, actor: bool = True, critic: bool = True) -> Count:
    """The per-state products of `policy` (a member policy or SB3's plain MlpPolicy / CnnPolicy) for its action
    parameters (`actor`) and/or its values (`critic`)."""
    net = policy.mlp_extractor
    if isinstance(net, MemberMLP):
        parts = [_tower(net.policy_tower, net.k)] * actor + [_tower(net.value_tower, net.k)] * critic
        return sum(parts[1:], parts[0]) if parts else Count(())
    if isinstance(net, MemberNatureCNN):
        return _member_cnn(net, _image_hw(policy), actor, critic)
    extractor = policy.features_extractor  # plain SB3: a shared extractor (NatureCNN) or a flat one
    trunk = list(extractor.modules()) if any(isinstance(m, (nn.Conv2d, nn.Linear)) for m in extractor.modules()) else []
    count = _plain(trunk, _image_hw(policy))
    if actor:
        count = count + _plain([*net.policy_net, policy.action_net], (1, 1))
    if critic:
        count = count + _plain([*net.value_net, policy.value_net], (1, 1))
    return count


def measurement_count(policy, measurement: str, discrete: bool) -> Count | None:
    """What a benchmark measurement needs per state; None for measurements without a count (training, memory).

    `predict` needs the action parameters of every member (the members are combined); the measures need the
    values too (value_std), except a plain policy's, whose max_prob and entropy read its action distribution.
    """
    if measurement.startswith("predict_b"):
        return network_count(policy, actor=True, critic=False)
    if measurement.startswith(("act_uncertainty_b", "uncertainty_b", "compiled_act_uncertainty_b")):
        plain = not isinstance(policy.mlp_extractor, (MemberMLP, MemberNatureCNN))
        return network_count(policy, actor=True, critic=not (plain and discrete))
    return None
