"""One batched call from a policy and N states to every uncertainty measure."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy

from paper_lib import measures
from paper_lib.methods.networks import to_members
from paper_lib.methods.policy import MemberActorCriticPolicy, combine_actions


@dataclass
class MemberOutputs:
    """Raw outputs of the k members on N states (for uncertainty, plots and analysis)."""

    values: np.ndarray  # (k, N)
    action_params: np.ndarray  # (k, N, A): logits (discrete) or action means (continuous)
    discrete: bool


def member_outputs(policy: ActorCriticPolicy, observations: np.ndarray, batch_size: int = 1024) -> MemberOutputs:
    """All members on all states, in batches of `batch_size` states, one forward pass each.

    `observations` are what the policy sees (after VecNormalize, if the env used it). A
    baseline policy is returned as a single member (k = 1).
    """
    discrete = isinstance(policy.action_space, spaces.Discrete)
    obs = np.asarray(observations)
    if obs.shape[0] == 0:
        raise ValueError("member_outputs got no observations; pass an array of shape (N, *obs_shape) with N >= 1")
    values, params = [], []
    policy.set_training_mode(False)
    with th.no_grad():
        for start in range(0, obs.shape[0], batch_size):
            tensor, _ = policy.obs_to_tensor(obs[start:start + batch_size])
            if isinstance(policy, MemberActorCriticPolicy):
                pi, vf = policy.member_outputs_from_tensor(tensor)
            else:
                pi, vf = _single_member(policy, tensor)
            values.append(vf.cpu().numpy())
            params.append(pi.cpu().numpy())
    return MemberOutputs(np.concatenate(values, axis=1), np.concatenate(params, axis=1), discrete)


def _single_member(policy: ActorCriticPolicy, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    features = policy.extract_features(obs)
    if policy.share_features_extractor:
        latent_pi, latent_vf = policy.mlp_extractor(features)
    else:
        latent_pi, latent_vf = policy.mlp_extractor.forward_actor(features[0]), policy.mlp_extractor.forward_critic(features[1])
    return policy.action_net(latent_pi)[None], policy.value_net(latent_vf).squeeze(-1)[None]


def uncertainty(policy: ActorCriticPolicy, observations: np.ndarray, measures_wanted: tuple[str, ...] | None = None,
                batch_size: int = 1024) -> dict[str, np.ndarray]:
    """Every applicable measure, each of shape (N,).

    value_std, policy_std and policy_js need members; max_prob and entropy exist for discrete
    actions only. A baseline policy (no members) gives max_prob and entropy; asking it for a
    member measure is an error. A baseline with continuous actions has no measure: {}.
    """
    out = member_outputs(policy, observations, batch_size)
    k = out.values.shape[0]
    available = (measures.MEMBER_MEASURES if k > 1 else ()) + (measures.DISCRETE_ONLY if out.discrete else ())
    wanted = available if measures_wanted is None else tuple(measures_wanted)
    for name in wanted:
        if name not in available:
            if name in measures.MEMBER_MEASURES and k == 1:
                raise ValueError(f"{name} needs ensemble members, but this policy has none (baseline); "
                                 "use a member method or ask for max_prob / entropy")
            raise ValueError(f"measure {name!r} is not available here; available: {available}")
    if not wanted:
        return {}  # a baseline with continuous actions: no measure applies (member-free detectors still do)
    computed = measures.all_measures(out.values, out.action_params, out.discrete) if k > 1 else {
        "max_prob": measures.max_prob(out.action_params), "entropy": measures.entropy(out.action_params)}
    return {name: computed[name] for name in wanted}


def policy_features(policy: ActorCriticPolicy, observations: np.ndarray, batch_size: int = 1024) -> np.ndarray:
    """The policy's last hidden layer on N states, (N, H): the input of its action head.

    For member policies the members' features are averaged, so a member-free detector
    (Mahalanobis, kNN) sees one feature vector per state like it would for the baseline.
    """
    obs = np.asarray(observations)
    chunks = []
    policy.set_training_mode(False)
    with th.no_grad():
        for start in range(0, obs.shape[0], batch_size):
            tensor, _ = policy.obs_to_tensor(obs[start:start + batch_size])
            chunks.append(_last_hidden(policy, tensor).cpu().numpy())
    return np.concatenate(chunks)


def _last_hidden(policy: ActorCriticPolicy, obs: th.Tensor) -> th.Tensor:
    features = policy.extract_features(obs)
    if isinstance(policy, MemberActorCriticPolicy):
        net = policy.mlp_extractor
        if hasattr(net, "policy_tower"):
            x = net.policy_tower[:-1](to_members(features, net.k, "all"))
        else:
            x = net.trunk(to_members(features, net.k, "all"))
        return x.mean(0)
    if not policy.share_features_extractor:
        features = features[0]
    return policy.mlp_extractor.forward_actor(features)


def act_with_uncertainty(policy: MemberActorCriticPolicy, observation: np.ndarray, deterministic: bool = True
                         ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Actions (combined as `predict` would) and every measure, from one batched pass over the members.

    The deployment call: an agent that acts and says how unsure it is, at the cost of one
    forward pass instead of `predict` plus `uncertainty` (two passes).
    """
    if not isinstance(policy, MemberActorCriticPolicy):
        raise ValueError("act_with_uncertainty needs a member policy; a baseline has no member-based uncertainty")
    if policy.training:
        policy.set_training_mode(False)
    tensor, vectorized = policy.obs_to_tensor(observation)
    with th.no_grad():
        pi, vf = policy.member_outputs_from_tensor(tensor)
        actions = combine_actions(pi, policy, *policy.inference, deterministic=deterministic).cpu().numpy()
    actions = actions.reshape((-1, *policy.action_space.shape))
    if isinstance(policy.action_space, spaces.Box):
        actions = np.clip(actions, policy.action_space.low, policy.action_space.high)
    discrete = isinstance(policy.action_space, spaces.Discrete)
    scores = measures.all_measures(vf.cpu().numpy(), pi.cpu().numpy(), discrete)
    return (actions if vectorized else actions[0]), scores
