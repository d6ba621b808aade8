"""A trained Masksembles or Ensemble MLP policy compiled for an agent acting one state at a time.

`act_with_uncertainty` costs 0.135 ms on one HalfCheetah state against a 0.015 ms arithmetic limit for
Masksembles (results/bench): torch's fixed cost per operation, not the products, is most of it. `compile_policy`
copies the weights once, laid out for the members' one-state products, and runs them in one compiled call
(`kernels`):
- each Masksembles member keeps only its mask's units: member j's layer is W[kept_out_j][:, kept_in_j] (the
  masks keep the same number of units for every member, so the members stack);
- an Ensemble's k weight matrices stack as they are stored;
- the policy and value towers' first layers (same input) are one layer.

Same numbers as `act_with_uncertainty` up to float rounding (tests/deploy); the weights are a snapshot: compile
again after training further. MC Dropout and MC DropConnect draw their masks from torch's per-state streams, and
Nature CNN policies need convolutions: both stay on `act_with_uncertainty`, as do sampled actions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.distributions import CategoricalDistribution, DiagGaussianDistribution
from stable_baselines3.common.torch_layers import FlattenExtractor
from torch import nn

from paper_lib.deploy import kernels
from paper_lib.measures.estimates import check_observations
from paper_lib.methods.layers import ENSEMBLE, SHARED, MasksemblesMask, MemberLinear
from paper_lib.methods.networks import MemberMLP
from paper_lib.methods.policy import MemberActorCriticPolicy

ACTIVATION_CODES = {nn.ReLU: kernels.RELU, nn.Tanh: kernels.TANH}
#: The clip before a log, as the torch measures take it (`measures.definitions._TINY`).
_TINY = 1e-12
_INSTEAD = "use paper_lib.measures.act_with_uncertainty, which covers every member policy"


class NotCompilable(ValueError):
    """A policy this path does not cover; the message names what to use instead."""


@dataclass(frozen=True)
class Layer:
    """One linear layer of all members: x (d_in,) @ weight[j] (d_in, d_out) + bias[j]; a leading size of 1 is
    shared by every member."""

    weight: np.ndarray  # (k or 1, d_in, d_out) float32
    bias: np.ndarray  # (k or 1, d_out) float32
    activation: int  # a `kernels` code, applied after the layer


def _tower_layers(tower: nn.Sequential, k: int) -> list[Layer]:
    """A tower's layers with each member's kept units gathered (Masksembles) or its own weights (Ensemble).

    A layer's kept input units are the previous layer's kept outputs; a layer before any mask is shared."""
    modules = list(tower)
    layers: list[Layer] = []
    kept_in: np.ndarray | None = None  # (k, d_in) boolean; None while every member sees every input unit
    for index, module in enumerate(modules):
        if not isinstance(module, MemberLinear):
            if isinstance(module, (MasksemblesMask, nn.Identity, *ACTIVATION_CODES)):
                continue
            raise NotCompilable(f"layer {type(module).__name__} has no compiled form (MC Dropout draws torch's "
                                f"per-state masks); {_INSTEAD}")
        following = modules[index + 1:index + 3]  # its activation, then its mask (layers.py's order)
        activation = next((ACTIVATION_CODES[type(m)] for m in following if type(m) in ACTIVATION_CODES), kernels.NONE)
        mask = next((m for m in following if isinstance(m, MasksemblesMask)), None)
        kept_out = None if mask is None else mask.masks.detach().cpu().numpy().astype(bool)
        layers.append(_member_layer(module, k, kept_in, kept_out, activation))
        kept_in = kept_out
    return layers


def _member_layer(module: MemberLinear, k: int, kept_in: np.ndarray | None, kept_out: np.ndarray | None,
                  activation: int) -> Layer:
    if module.mode == ENSEMBLE:  # stored (k, d_in, d_out) and (k, 1, d_out)
        if kept_in is not None or kept_out is not None:
            raise NotCompilable(f"an Ensemble layer beside a Masksembles mask; {_INSTEAD}")
        return Layer(_array(module.weight), _array(module.bias)[:, 0], activation)
    if module.mode != SHARED:
        raise NotCompilable(f"MemberLinear mode {module.mode!r} draws torch's per-state masks (MC DropConnect); "
                            f"{_INSTEAD}")
    weight = _array(module.weight).reshape(module.d_out, module.d_in).T  # (d_in, d_out)
    bias = _array(module.bias).reshape(module.d_out)
    if kept_in is None and kept_out is None:
        return Layer(_array(weight[None]), _array(bias[None]), activation)
    rows = [np.ones(module.d_in, bool)] * k if kept_in is None else list(kept_in)
    cols = [np.ones(module.d_out, bool)] * k if kept_out is None else list(kept_out)
    return Layer(_array(np.stack([weight[r][:, c] for r, c in zip(rows, cols)])),
                 _array(np.stack([bias[c] for c in cols])), activation)


def _array(x) -> np.ndarray:  # noqa: ANN001 (a tensor or an array)
    x = x.detach().cpu().numpy() if hasattr(x, "detach") else x
    return np.ascontiguousarray(x, dtype=np.float32).copy()


def _fuse_first(policy_first: Layer, value_first: Layer) -> Layer:
    """The towers' first layers as one product: the same input, their outputs side by side (policy first)."""
    if policy_first.activation != value_first.activation:
        raise NotCompilable(f"the policy and value towers' first activations differ; {_INSTEAD}")
    members = max(len(policy_first.weight), len(value_first.weight))

    def widened(x: np.ndarray) -> np.ndarray:
        return np.broadcast_to(x, (members, *x.shape[1:]))

    return Layer(_array(np.concatenate([widened(policy_first.weight), widened(value_first.weight)], axis=-1)),
                 _array(np.concatenate([widened(policy_first.bias), widened(value_first.bias)], axis=-1)),
                 policy_first.activation)


def _packed(layers: list[Layer]) -> tuple[np.ndarray, np.ndarray]:
    """`kernels`' form of layers: every weight and bias in one float32 array, and the table that finds them."""
    parts, rows, offset = [], [], 0
    for layer in layers:
        members, d_in, d_out = layer.weight.shape
        rows.append((offset, offset + layer.weight.size, members, d_in, d_out, layer.activation))
        parts += [layer.weight.transpose(0, 2, 1).ravel(), layer.bias.ravel()]  # output-major: a row per output
        offset += layer.weight.size + layer.bias.size
    return np.concatenate(parts).astype(np.float32), np.array(rows, np.int64)


def _softmax(logits: np.ndarray) -> np.ndarray:
    shifted = np.exp(logits - logits.max(-1, keepdims=True))
    return shifted / shifted.sum(-1, keepdims=True)


def _kl(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return (p * (np.log(np.maximum(p, _TINY)) - np.log(np.maximum(q, _TINY)))).sum(-1)


class CompiledMemberPolicy:
    """`act_with_uncertainty` of a compiled member policy: deterministic actions (combined as `predict` combines
    them) and every member measure, from weights copied at compile time."""

    def __init__(self, policy: MemberActorCriticPolicy):
        check_compilable(policy)
        extractor: MemberMLP = policy.mlp_extractor
        self.policy = policy  # its spaces, for `check_observations`
        self.k = policy.n_members
        self.discrete = isinstance(policy.action_space, spaces.Discrete)
        self.mode = policy.inference[0]
        policy_layers = _tower_layers(extractor.policy_tower, self.k)
        value_layers = _tower_layers(extractor.value_tower, self.k)
        if min(len(policy_layers), len(value_layers)) < 2:
            raise NotCompilable(f"towers without a hidden layer (net_arch []) are not covered; {_INSTEAD}")
        self.packed, self.table = _packed([_fuse_first(policy_layers[0], value_layers[0]), *policy_layers[1:],
                                           *value_layers[1:]])
        self.n_policy_layers, self.split = len(policy_layers) - 1, policy_layers[0].weight.shape[-1]
        space = policy.action_space
        if not self.discrete:
            self.low, self.high = space.low.astype(np.float32), space.high.astype(np.float32)
        self.action_shape = space.shape

    def act_with_uncertainty(self, observation: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """(actions, {measure: (N,)}) for one observation or a batch, as `measures.act_with_uncertainty`."""
        obs, vectorized = check_observations(self.policy, observation, single_ok=True, what="observation")
        program = (np.ascontiguousarray(obs, dtype=np.float32), self.packed, self.table, self.n_policy_layers,
                   self.split, self.k)
        if self.discrete:
            actions, scores = self._discrete(*kernels.forward(*program))
        else:
            actions, value_std, policy_std, policy_js = kernels.act_continuous(*program, self.low, self.high)
            actions = actions.reshape((-1, *self.action_shape))
            scores = {"value_std": value_std, "policy_std": policy_std, "policy_js": policy_js}
        return (actions if vectorized else actions[0]), scores

    def _discrete(self, logits: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The combined actions and every measure of discrete members, in numpy (`measures.definitions`)."""
        k, n_actions = len(logits), logits.shape[-1]
        scores = {"value_std": values.std(0), "policy_std": logits.std(0).mean(-1)}
        probs = _softmax(logits)
        p, q = probs[:, None], probs[None, :]
        m = 0.5 * (p + q)
        scores["policy_js"] = (0.5 * _kl(p, m) + 0.5 * _kl(q, m)).reshape(k * k, -1).max(0)
        mean = probs.mean(0)
        scores["max_prob"] = 1.0 - mean.max(-1)
        scores["entropy"] = -(mean * np.log(np.maximum(mean, _TINY))).sum(-1)
        if self.mode == "average":
            return mean.argmax(-1), scores
        counts = (logits.argmax(-1)[..., None] == np.arange(n_actions)).sum(0)  # (N, A) member votes
        tied = counts == counts.max(-1, keepdims=True)
        return np.where(tied, mean, -1.0).argmax(-1), scores  # the tied action most probable on average


def check_compilable(policy: object) -> None:
    """One NotCompilable naming what this path covers and what to use instead, or nothing."""
    if not isinstance(policy, MemberActorCriticPolicy):
        raise NotCompilable(f"compile_policy takes a member policy (Masksembles or Ensemble), not "
                            f"{type(policy).__name__}; a baseline has no member measures")
    if not isinstance(policy.mlp_extractor, MemberMLP) or not isinstance(policy.features_extractor, FlattenExtractor):
        raise NotCompilable(f"only MLP policies on flat observations compile; {_INSTEAD}")
    if not isinstance(policy.action_dist, (DiagGaussianDistribution, CategoricalDistribution)):
        raise NotCompilable(f"action distribution {type(policy.action_dist).__name__} is not covered; {_INSTEAD}")
    mode = policy.inference[0]
    discrete = isinstance(policy.action_space, spaces.Discrete)
    if mode not in ("vote", "average") or (discrete and policy.inference_options["ties"] != "mean_prob"):
        raise NotCompilable(f"inference {policy.inference} with options {policy.inference_options} is not covered "
                            f"(members combined by 'vote' or 'average', ties by 'mean_prob'); {_INSTEAD}")


def compile_policy(policy: MemberActorCriticPolicy) -> CompiledMemberPolicy:
    """The policy's weights (or an SB3 algorithm's policy's) compiled for one-state acting with uncertainty."""
    if not isinstance(policy, nn.Module) and hasattr(policy, "policy"):
        policy = policy.policy
    return CompiledMemberPolicy(policy)
