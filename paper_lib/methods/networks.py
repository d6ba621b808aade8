"""The member networks: MLP towers (MuJoCo) and the Nature CNN (Atari), one per method.

Both expose SB3's `mlp_extractor` interface (`forward`, `forward_actor`, `forward_critic`,
`latent_dim_pi`, `latent_dim_vf`), but their "latents" are already the final outputs (action
means or logits, and values): member methods need their own heads (ensembles) or a
stochastic layer right before the heads, so the heads live here and the policy's
`action_net` / `value_net` are identities.

Batches reach the members in one of two layouts:
- split: a batch of B = k*n rows, consecutive chunk j goes through member j. This is how
  rollouts (env group j -> member j) and the PPO update (chunk j of each minibatch) work.
- all:   every member sees every row; the (k, N, ...) outputs feed inference and uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch as th
from torch import nn

from paper_lib.methods.layers import (
    DROPCONNECT,
    ENSEMBLE,
    SHARED,
    MasksemblesMask,
    MCDropout,
    MemberConv2d,
    MemberLinear,
    validate_masksembles,
)

MEMBER_METHODS = ("masksembles", "mc_dropout", "mc_dropconnect", "ensemble")
METHODS = ("baseline", *MEMBER_METHODS)

#: Hidden layers (0-based) followed by a stochastic layer: the paper's "after the first and
#: second hidden layer". DropConnect instead drops weights of the layers consuming them.
STOCHASTIC_HIDDEN = (0, 1)


@dataclass(frozen=True)
class MemberSpec:
    """What makes the k members differ; validated on construction."""

    method: str
    n_members: int = 4
    dropout_p: float = 0.1
    masksembles_scale: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.method not in MEMBER_METHODS:
            raise ValueError(f"unknown member method {self.method!r}; use one of {MEMBER_METHODS}")
        if self.n_members < 2:
            raise ValueError(f"n_members={self.n_members}: a member method needs k >= 2 members")
        if not 0.0 <= self.dropout_p < 1.0:
            raise ValueError(f"dropout_p={self.dropout_p} is outside [0, 1)")

    def weight_mode(self, consumes_stochastic: bool) -> str:
        if self.method == "ensemble":
            return ENSEMBLE
        if self.method == "mc_dropconnect" and consumes_stochastic:
            return DROPCONNECT
        return SHARED

    def stochastic(self, width: int, seed_offset: int) -> nn.Module:
        """The layer after a hidden layer: a Masksembles mask, MC Dropout, or nothing."""
        if self.method == "masksembles":
            return MasksemblesMask(width, self.n_members, self.masksembles_scale, self.seed * 1009 + seed_offset)
        if self.method == "mc_dropout":
            return MCDropout(self.dropout_p)
        return nn.Identity()

    def check_widths(self, widths: list[int]) -> None:
        if self.method == "masksembles":
            for width in widths:
                validate_masksembles(width, self.n_members, self.masksembles_scale)


def to_members(x: th.Tensor, k: int, layout: str) -> th.Tensor:
    """(B, ...) -> (k, n, ...) in the split or all layout."""
    if layout == "all":
        return x.unsqueeze(0).expand(k, *x.shape)
    if x.shape[0] % k != 0:
        raise ValueError(
            f"a batch of {x.shape[0]} rows cannot be split over {k} members; batches must be a multiple of k "
            "(use n_envs and batch_size divisible by n_members, or wrap the VecEnv in MemberGroupVecEnv)"
        )
    return x.reshape(k, x.shape[0] // k, *x.shape[1:])


def from_members(y: th.Tensor) -> th.Tensor:
    return y.reshape(y.shape[0] * y.shape[1], *y.shape[2:])


class MemberActorCritic(nn.Module):
    """Common SB3-facing interface; subclasses implement `members(features, layout)`."""

    def __init__(self, spec: MemberSpec, action_dim: int):
        super().__init__()
        self.spec = spec
        self.k = spec.n_members
        self.latent_dim_pi = action_dim
        self.latent_dim_vf = 1

    def members(self, features: th.Tensor, layout: str, actor: bool = True, critic: bool = True):
        raise NotImplementedError

    def forward(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        pi, vf = self.members(features, "split")
        return from_members(pi), from_members(vf)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return from_members(self.members(features, "split", critic=False)[0])

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        return from_members(self.members(features, "split", actor=False)[1])


def _mlp_tower(d_in: int, hidden: list[int], d_out: int, spec: MemberSpec, activation: type[nn.Module],
               out_gain: float, seed_offset: int, ortho_init: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    sizes = [d_in, *hidden]
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers += [MemberLinear(a, b, spec.n_members, spec.weight_mode(i - 1 in STOCHASTIC_HIDDEN), spec.dropout_p,
                                ortho_init=ortho_init),
                   activation()]
        if i in STOCHASTIC_HIDDEN:
            layers.append(spec.stochastic(b, seed_offset + i))
    last = len(hidden) - 1
    layers.append(MemberLinear(sizes[-1], d_out, spec.n_members, spec.weight_mode(last in STOCHASTIC_HIDDEN),
                               spec.dropout_p, gain=out_gain, ortho_init=ortho_init))
    return nn.Sequential(*layers)


class MemberMLP(MemberActorCritic):
    """Separate policy and value MLPs (paper appendix A), each with its stochastic layers."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: list[int], spec: MemberSpec,
                 activation: type[nn.Module] = nn.Tanh, ortho_init: bool = True):
        super().__init__(spec, action_dim)
        spec.check_widths([w for i, w in enumerate(hidden) if i in STOCHASTIC_HIDDEN])
        self.policy_tower = _mlp_tower(obs_dim, hidden, action_dim, spec, activation, 0.01, 0, ortho_init)
        self.value_tower = _mlp_tower(obs_dim, hidden, 1, spec, activation, 1.0, 100, ortho_init)

    def members(self, features: th.Tensor, layout: str, actor: bool = True, critic: bool = True):
        x = to_members(features, self.k, layout)
        return (self.policy_tower(x) if actor else None), (self.value_tower(x) if critic else None)


class MemberNatureCNN(MemberActorCritic):
    """The Nature CNN shared by policy and value heads (Mnih et al. 2015; SB3's NatureCNN).

    Stochastic layers sit after the first convolution and after the final fully-connected
    layer (paper appendix A); an ensemble is k separate CNNs with their own heads, run as
    grouped convolutions and batched matmuls.
    """

    def __init__(self, obs_shape: tuple[int, int, int], action_dim: int, spec: MemberSpec, features_dim: int = 512,
                 ortho_init: bool = True):
        super().__init__(spec, action_dim)
        spec.check_widths([32, features_dim])
        k, p, o = spec.n_members, spec.dropout_p, ortho_init
        c, h, w = obs_shape
        self.conv1 = MemberConv2d(c, 32, 8, 4, k, spec.weight_mode(False), p, ortho_init=o)
        self.after_conv1 = spec.stochastic(32, 0)
        self.conv2 = MemberConv2d(32, 64, 4, 2, k, spec.weight_mode(True), p, ortho_init=o)
        self.conv3 = MemberConv2d(64, 64, 3, 1, k, spec.weight_mode(False), p, ortho_init=o)
        n_flat = 64 * _conv_out(_conv_out(_conv_out(h, 8, 4), 4, 2), 3, 1) * _conv_out(_conv_out(_conv_out(w, 8, 4), 4, 2), 3, 1)
        self.fc = MemberLinear(n_flat, features_dim, k, spec.weight_mode(False), p, ortho_init=o)
        self.after_fc = spec.stochastic(features_dim, 1)
        self.policy_head = MemberLinear(features_dim, action_dim, k, spec.weight_mode(True), p, gain=0.01, ortho_init=o)
        self.value_head = MemberLinear(features_dim, 1, k, spec.weight_mode(True), p, gain=1.0, ortho_init=o)

    def trunk(self, x: th.Tensor) -> th.Tensor:
        x = self.after_conv1(th.relu(self.conv1(x)))
        x = th.relu(self.conv3(th.relu(self.conv2(x))))
        return self.after_fc(th.relu(self.fc(x.flatten(2))))

    def members(self, features: th.Tensor, layout: str, actor: bool = True, critic: bool = True):
        z = self.trunk(to_members(features, self.k, layout))
        return (self.policy_head(z) if actor else None), (self.value_head(z) if critic else None)


def _conv_out(size: int, kernel: int, stride: int) -> int:
    return (size - kernel) // stride + 1
