"""One batched call from a policy and N states to every uncertainty measure.

MC methods (MC Dropout, MC DropConnect) sample their k members per state: each state gets
its own seed, drawn up front for all N states from `seed` (or from torch's RNG when None),
so a state's scores do not depend on the batch it is scored in, and the same seed gives the
same scores whatever `batch_size` is.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.preprocessing import is_image_space

from paper_lib.measures import definitions as measures
from paper_lib.methods.inference import check_path, fast_arithmetic
from paper_lib.methods.policy import MemberActorCriticPolicy, check_finite, combine_actions, draw_state_seeds


@dataclass
class MemberOutputs:
    """Raw outputs of the k members on N states (for uncertainty, plots and analysis)."""

    values: np.ndarray  # (k, N)
    action_params: np.ndarray  # (k, N, A): logits (discrete) or action means (continuous)
    discrete: bool


def check_observations(policy: ActorCriticPolicy, observations: np.ndarray, *, single_ok: bool = False,
                       what: str = "observations") -> tuple[np.ndarray, bool]:
    """`observations` as an (N, *obs_shape) array with N >= 1 and finite values, or one ValueError.

    Returns (batch, vectorized); a single observation (no batch axis) is accepted where
    `single_ok`. Channel-last images are accepted for image policies, as SB3 accepts them.
    """
    obs = np.asarray(observations)
    space = policy.observation_space
    shapes = [tuple(space.shape)]
    if obs.shape[1:] != shapes[0] and obs.shape != shapes[0] and is_image_space(space) and len(space.shape) == 3:
        shapes.append((space.shape[1], space.shape[2], space.shape[0]))  # SB3 transposes channel-last images
    if single_ok and obs.shape in shapes:
        obs, vectorized = obs[None], False
    else:
        vectorized = True
    if obs.ndim == 0 or obs.shape[1:] not in shapes or obs.shape[0] == 0 or obs.dtype == object:
        expected = " or ".join(f"(N, {', '.join(map(str, s))})" for s in shapes)
        raise ValueError(f"{what} have shape {obs.shape} but this policy takes {expected} with N >= 1 "
                         f"(its observation space is {space}); pass states of the env it was trained on, "
                         "stacked along a first axis")
    check_finite(obs, what=what)  # NaN, inf, or a float64 that is inf as float32
    check_pixel_range(space, obs, what)
    return obs, vectorized


def check_pixel_range(space: spaces.Space, obs: np.ndarray, what: str = "observations") -> None:
    """Integer (pixel) spaces take their own dtype's values: frames scaled to [0, 1] or negative ints would be scored
    as other frames (the policy divides by 255 itself). Float spaces' bounds are not enforced: OOD states may leave them."""
    if not isinstance(space, spaces.Box) or not np.issubdtype(space.dtype, np.integer):
        return
    low, high = int(np.min(space.low)), int(np.max(space.high))
    if not np.issubdtype(obs.dtype, np.integer):
        raise ValueError(f"{what} are {obs.dtype} but this policy's observation space holds {space.dtype} frames in "
                         f"[{low}, {high}]; pass the raw frames (the policy scales them itself), not frames divided "
                         "by 255 or converted to float")
    lowest, highest = int(obs.min()), int(obs.max())
    if lowest < low or highest > high:
        raise ValueError(f"{what} hold values in [{lowest}, {highest}] but this policy's observation space holds "
                         f"{space.dtype} frames in [{low}, {high}]; pass the raw frames as the env returns them")


def as_policy(model_or_policy: Any, where: str = "uncertainty") -> ActorCriticPolicy:
    """The policy of an SB3 model, or the policy itself: `uncertainty(model, obs)` means `model.policy`."""
    if isinstance(model_or_policy, BaseAlgorithm):
        model_or_policy = model_or_policy.policy
    if not isinstance(model_or_policy, ActorCriticPolicy):
        raise ValueError(f"{where} takes an SB3 actor-critic model or its policy (model.policy), got "
                         f"{type(model_or_policy).__name__}; pass e.g. make_agent(...) or PPO.load(path)")
    return model_or_policy


def check_sample_seed(seed: Any) -> int | None:
    """None or an integer: int() would read seed=1.5 as 1 and "7" as 7, the scores of another seed without a word."""
    if seed is None or (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0):
        return None if seed is None else int(seed)
    raise ValueError(f"seed must be None or an integer >= 0 (the MC masks' seed), got {seed!r}; pass e.g. seed=0")


def check_batch_size(batch_size: Any) -> int:
    """States per forward pass: a positive integer (0 would loop forever or return nothing)."""
    if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer (states per forward pass), got {batch_size!r}; "
                         "use e.g. batch_size=1024")
    return int(batch_size)


def _state_seeds(policy: ActorCriticPolicy, n: int, seed: int | None) -> np.ndarray | None:
    """One seed per state, for every state at once (so batching cannot change them); None without MC layers."""
    if not (isinstance(policy, MemberActorCriticPolicy) and policy.samples_members):
        return None
    generator = None if seed is None else th.Generator().manual_seed(int(seed))
    return draw_state_seeds(n, generator)


def _batches(policy: ActorCriticPolicy, obs: np.ndarray, batch_size: int, seed: int | None, actor: bool = True,
             critic: bool = True, path: str = "exact") -> Iterator[tuple[th.Tensor | None, th.Tensor | None]]:
    """(k, n, A) action params and (k, n) values of successive batches of `obs`, without autograd.

    A baseline policy is a single member (k = 1). The per-state seeds of MC methods are drawn
    for all states up front, so the batching cannot change them. A member policy skips the
    output not asked for (None); its MC masks do not depend on that. `path` is the lean path's (`inference.PATHS`).
    """
    seeds = _state_seeds(policy, len(obs), seed)
    policy.set_training_mode(False)
    with th.no_grad():
        for start in range(0, obs.shape[0], batch_size):
            tensor, _ = policy.obs_to_tensor(obs[start:start + batch_size])
            if isinstance(policy, MemberActorCriticPolicy):
                yield policy.member_outputs_from_tensor(tensor, None if seeds is None else seeds[start:start + batch_size],
                                                        actor=actor, critic=critic, path=path)
            else:
                yield _single_member(policy, tensor)


def member_outputs(policy: ActorCriticPolicy | BaseAlgorithm, observations: np.ndarray, batch_size: int = 1024,
                   seed: int | None = None, path: str = "exact") -> MemberOutputs:
    """All members on all states, in batches of `batch_size` states, one forward pass each.

    `observations` are what the policy sees (after VecNormalize, if the env used it). A
    baseline policy is returned as a single member (k = 1). MC methods sample per (member,
    state) from per-state seeds drawn from `seed` (torch's global RNG when None). `path`: see `uncertainty`.
    """
    policy, seed, path = as_policy(policy, "member_outputs"), check_sample_seed(seed), check_path(path)
    discrete = isinstance(policy.action_space, spaces.Discrete)
    batch_size = check_batch_size(batch_size)
    obs, _ = check_observations(policy, observations)
    values, params = [], []
    for pi, vf in _batches(policy, obs, batch_size, seed, path=path):
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


def uncertainty(policy: ActorCriticPolicy | BaseAlgorithm, observations: np.ndarray, measures_wanted: tuple[str, ...] | None = None,
                batch_size: int = 1024, seed: int | None = None, path: str = "exact") -> dict[str, np.ndarray]:
    """Every applicable measure, each of shape (N,).

    value_std, policy_std and policy_js need members; max_prob and entropy exist for discrete
    actions only. A baseline policy (no members) gives max_prob and entropy; asking it for a
    member measure is an error. A baseline with continuous actions has no measure: {}.
    `seed` fixes the MC methods' samples (see `member_outputs`). The measures are computed in
    torch on each batch's member outputs (`measures.torch_measures`); only they become numpy.
    `path` ("exact" or "fast", `inference.PATHS`): on batches of 64 states or more, "exact" gives the numbers the
    committed scores were computed with, bit for bit (the scoring stage's default), "fast" the same up to float
    rounding in about half the time (`act_with_uncertainty`, `predict` and the benchmark use it).
    """
    policy, seed, path = as_policy(policy), check_sample_seed(seed), check_path(path)
    batch_size = check_batch_size(batch_size)
    obs, _ = check_observations(policy, observations)
    discrete = isinstance(policy.action_space, spaces.Discrete)
    k = policy.n_members if isinstance(policy, MemberActorCriticPolicy) else 1
    available = (measures.MEMBER_MEASURES if k > 1 else ()) + (measures.DISCRETE_ONLY if discrete else ())
    if isinstance(measures_wanted, str):  # one name, not its letters: uncertainty(p, obs, "value_std")
        measures_wanted = (measures_wanted,)
    wanted = available if measures_wanted is None else tuple(measures_wanted)
    for name in wanted:
        if name not in available:
            if name in measures.MEMBER_MEASURES and k == 1:
                raise ValueError(f"{name} needs ensemble members, but this policy has none (baseline); "
                                 "use a member method or ask for max_prob / entropy")
            raise ValueError(f"measure {name!r} is not available here; available: {available}")
    if not wanted:
        return {}  # a baseline with continuous actions: no measure applies (member-free detectors still do)
    parts: dict[str, list[th.Tensor]] = {name: [] for name in wanted}
    value_only = set(wanted) == {"value_std"}
    for pi, vf in _batches(policy, obs, batch_size, seed, actor=not value_only, critic="value_std" in wanted,
                           path=path):
        exact = not fast_arithmetic(path, (vf if pi is None else pi).shape[1])
        for name, value in measures.torch_measures(vf, pi, discrete, wanted, exact).items():
            parts[name].append(value)
    return {name: th.cat(values).cpu().numpy() for name, values in parts.items()}


def policy_features(policy: ActorCriticPolicy | BaseAlgorithm, observations: np.ndarray, batch_size: int = 1024,
                    seed: int | None = None, path: str = "exact") -> np.ndarray:
    """The policy's last hidden layer on N states, (N, H): the input of its action head.

    For member policies the members' features are averaged, so a member-free detector
    (Mahalanobis, kNN) sees one feature vector per state like it would for the baseline.
    MC methods sample per (member, state), seeded like `member_outputs`. `path`: see `uncertainty`.
    """
    policy, seed, path = as_policy(policy, "policy_features"), check_sample_seed(seed), check_path(path)
    batch_size = check_batch_size(batch_size)
    obs, _ = check_observations(policy, observations)
    seeds = _state_seeds(policy, len(obs), seed)
    chunks = []
    policy.set_training_mode(False)
    with th.no_grad():
        for start in range(0, obs.shape[0], batch_size):
            tensor, _ = policy.obs_to_tensor(obs[start:start + batch_size])
            chunks.append(_last_hidden(policy, tensor, None if seeds is None else seeds[start:start + batch_size], path)
                          .cpu().numpy())
    return np.concatenate(chunks)


def _last_hidden(policy: ActorCriticPolicy, obs: th.Tensor, state_seeds: np.ndarray | None = None,
                 path: str = "exact") -> th.Tensor:
    if isinstance(policy, MemberActorCriticPolicy):
        return policy.last_hidden_from_tensor(obs, state_seeds, path).mean(0)
    features = policy.extract_features(obs)
    if not policy.share_features_extractor:
        features = features[0]
    return policy.mlp_extractor.forward_actor(features)


def act_with_uncertainty(policy: MemberActorCriticPolicy, observation: np.ndarray, deterministic: bool = True
                         ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Actions (combined as `predict` would) and every measure, from one batched pass over the members.

    The deployment call: an agent that acts and says how unsure it is, at the cost of one
    forward pass instead of `predict` plus `uncertainty` (two passes); the measures are
    computed in torch on that pass's outputs. It takes the "fast" path (see `uncertainty`), which on
    fewer than 64 states (an agent acting) is the exact one, bit for bit.
    """
    if not isinstance(policy, MemberActorCriticPolicy):
        raise ValueError("act_with_uncertainty needs a member policy; a baseline has no member-based uncertainty")
    observation, vectorized = check_observations(policy, observation, single_ok=True, what="observation")
    if policy.training:
        policy.set_training_mode(False)
    tensor = _checked_to_tensor(policy, observation)
    discrete = isinstance(policy.action_space, spaces.Discrete)
    with th.inference_mode():  # no version counters or view tracking: a few us of a one-state call; only numpy leaves
        pi, vf = policy.member_outputs_from_tensor(tensor, path="fast")
        actions = combine_actions(pi, policy, *policy.inference, deterministic=deterministic,
                                  **policy.inference_options).cpu().numpy()
        exact = not fast_arithmetic("fast", len(observation))
        measured = measures.torch_measures(vf, pi, discrete, exact=exact)
        scores = {name: value.cpu().numpy() for name, value in measured.items()}
    actions = actions.reshape((-1, *policy.action_space.shape))
    if isinstance(policy.action_space, spaces.Box):  # np.clip, as SB3's predict; this form is faster on small arrays
        actions = np.minimum(np.maximum(actions, policy.action_space.low), policy.action_space.high)
    return (actions if vectorized else actions[0]), scores


def _checked_to_tensor(policy: ActorCriticPolicy, observation: np.ndarray) -> th.Tensor:
    """SB3's `obs_to_tensor` of a batch `check_observations` accepted; flat observations without
    its checks and copy, which cost more than a one-state forward pass's layers."""
    if observation.shape[1:] == policy.observation_space.shape and not is_image_space(policy.observation_space):
        # SB3's `policy.device` walks the parameters (~5 us); this buffer moves with them
        return th.as_tensor(observation, device=policy._buffers["_inference_mode"].device)
    return policy.obs_to_tensor(observation)[0]
