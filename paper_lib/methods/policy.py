"""The SB3 policy: one ActorCriticPolicy subclass for every member method.

SB3's own `forward`, `evaluate_actions`, `get_distribution` and `predict_values` run
unchanged on the member network in the *split* layout (chunk j of a batch -> member j), which
is exactly what rollouts (env group j acts with member j) and the shared-buffer update need.
This class only adds what SB3 cannot know about:
- `_predict` combines the members (vote / average) or uses a single one (paper section 4.2);
- a truncated episode's bootstrap value comes from the member of that episode's env group,
  which `MemberGroupVecEnv` tags onto the terminal observation;
- `member_outputs` returns all k members' raw outputs for uncertainty and analysis.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import CategoricalDistribution, DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.preprocessing import is_image_space
from torch import nn

from paper_lib.methods.groups import MEMBER_TAG
from paper_lib.methods.networks import MemberActorCritic, MemberMLP, MemberNatureCNN, MemberSpec

INFERENCE_MODES = ("vote", "average", "single")


class ImagePassthrough(BaseFeaturesExtractor):
    """Hands the preprocessed image to the member CNN, which owns every conv layer."""

    def __init__(self, observation_space: spaces.Box):
        super().__init__(observation_space, features_dim=int(np.prod(observation_space.shape)))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return observations


class MemberActorCriticPolicy(ActorCriticPolicy):
    """Actor-critic policy with k members (Masksembles, MC Dropout, MC DropConnect, Ensemble).

    :param method: one of paper_lib.METHODS except "baseline"
    :param n_members: k, the number of members (masks, samples or networks)
    :param hidden_sizes: hidden widths of the policy and of the value MLP (ignored for images)
    :param dropout_p: drop probability of MC Dropout / MC DropConnect
    :param masksembles_scale: the Masksembles overlap parameter (reference `scale`, in [1, 6])
    :param member_seed: seeds the Masksembles masks, so a run's masks follow from its seed
    :param inference: "vote", "average" or "single" (changeable later with `set_inference`)
    :param inference_member: the member used by "single" inference, or None for a random one
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule,
        method: str = "masksembles",
        n_members: int = 4,
        hidden_sizes: tuple[int, ...] = (64, 64),
        dropout_p: float = 0.1,
        masksembles_scale: float = 2.0,
        member_seed: int = 0,
        inference: str = "vote",
        inference_member: int | None = None,
        activation_fn: type[nn.Module] = nn.Tanh,
        **kwargs: Any,
    ):
        if not isinstance(action_space, (spaces.Box, spaces.Discrete)):
            raise ValueError(f"member policies support Box and Discrete action spaces, got {action_space}")
        self.member_spec = MemberSpec(method, n_members, dropout_p, masksembles_scale, member_seed)
        self.hidden_sizes = list(hidden_sizes)
        if not kwargs.pop("share_features_extractor", True):
            raise ValueError("member policies own their whole network; share_features_extractor=False is not supported")
        if is_image_space(observation_space):
            kwargs.setdefault("features_extractor_class", ImagePassthrough)
        super().__init__(observation_space, action_space, lr_schedule, activation_fn=activation_fn, **kwargs)
        if self.use_sde:
            raise ValueError("gSDE is not supported by member policies; pass use_sde=False")
        self.register_buffer("_inference_mode", th.tensor(0))
        self.register_buffer("_inference_member", th.tensor(-1))
        self.set_inference(inference, inference_member)

    # --- construction --------------------------------------------------------------------
    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        spec = self.member_spec
        data.update(method=spec.method, n_members=spec.n_members, hidden_sizes=tuple(self.hidden_sizes),
                    dropout_p=spec.dropout_p, masksembles_scale=spec.masksembles_scale, member_seed=spec.seed)
        return data

    @property
    def n_members(self) -> int:
        return self.member_spec.n_members

    def _build_mlp_extractor(self) -> None:
        action_dim = int(self.action_space.n) if isinstance(self.action_space, spaces.Discrete) else int(
            np.prod(self.action_space.shape))
        if isinstance(self.features_extractor, ImagePassthrough):
            self.mlp_extractor: MemberActorCritic = MemberNatureCNN(self.observation_space.shape, action_dim,
                                                                    self.member_spec, ortho_init=self.ortho_init)
        else:
            self.mlp_extractor = MemberMLP(self.features_dim, action_dim, self.hidden_sizes, self.member_spec,
                                           self.activation_fn, ortho_init=self.ortho_init)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        # The member network already ends in the heads; SB3's extra linear heads would only
        # add parameters that never see a gradient.
        self.action_net, self.value_net = nn.Identity(), nn.Identity()
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    # --- inference mode ------------------------------------------------------------------
    def set_inference(self, mode: str, member: int | None = None) -> None:
        """Choose how `predict` turns k members into one action; saved with the model."""
        if mode not in INFERENCE_MODES:
            raise ValueError(f"unknown inference mode {mode!r}; use one of {INFERENCE_MODES}")
        if member is not None and not 0 <= member < self.n_members:
            raise ValueError(f"inference_member={member} is not in [0, {self.n_members - 1}]")
        self._inference_mode.fill_(INFERENCE_MODES.index(mode))
        self._inference_member.fill_(-1 if member is None else member)

    @property
    def inference(self) -> tuple[str, int | None]:
        member = int(self._inference_member)
        return INFERENCE_MODES[int(self._inference_mode)], (None if member < 0 else member)

    # --- member outputs ------------------------------------------------------------------
    def member_outputs_from_tensor(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """All k members on every state, one batched pass: (k, N, A) action params and (k, N) values."""
        features = self.extract_features(obs)
        pi, vf = self.mlp_extractor.members(features, "all")
        return pi, vf.squeeze(-1)

    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        features = self.extract_features(observation)
        pi, _ = self.mlp_extractor.members(features, "all", critic=False)
        return combine_actions(pi, self, *self.inference, deterministic=deterministic)

    # --- truncated-episode bootstrap ----------------------------------------------------
    def obs_to_tensor(self, observation):
        member = getattr(observation, MEMBER_TAG, None)
        tensor, vectorized = super().obs_to_tensor(observation)
        if member is not None:
            setattr(tensor, MEMBER_TAG, member)
        return tensor, vectorized

    def predict_values(self, obs: th.Tensor) -> th.Tensor:
        member = getattr(obs, MEMBER_TAG, None)
        if member is None:
            return super().predict_values(obs)
        features = super(ActorCriticPolicy, self).extract_features(obs, self.vf_features_extractor)
        _, vf = self.mlp_extractor.members(features, "all", actor=False)
        return vf[member]


def combine_actions(pi: th.Tensor, policy: ActorCriticPolicy, mode: str, member: int | None,
                    deterministic: bool) -> th.Tensor:
    """Turn the k members' action parameters (k, N, A) into N actions (paper section 4.2)."""
    dist = policy.action_dist
    if mode == "single":
        m = int(th.randint(pi.shape[0], ())) if member is None else member
        return _distribution(dist, pi[m], policy).get_actions(deterministic=deterministic)
    if isinstance(dist, DiagGaussianDistribution):  # continuous: vote and average both average the means
        return _distribution(dist, pi.mean(0), policy).get_actions(deterministic=deterministic)
    assert isinstance(dist, CategoricalDistribution)
    if mode == "average":
        probs = th.softmax(pi, -1).mean(0)
        return probs.argmax(-1) if deterministic else th.multinomial(probs, 1).squeeze(-1)
    # vote: each member's action (argmax, or a sample when stochastic), majority, random ties
    member_actions = pi.argmax(-1) if deterministic else th.distributions.Categorical(logits=pi).sample()
    counts = nn.functional.one_hot(member_actions, pi.shape[-1]).sum(0).float()
    return (counts + 0.5 * th.rand_like(counts)).argmax(-1)


def _distribution(dist, params: th.Tensor, policy: ActorCriticPolicy):
    if isinstance(dist, DiagGaussianDistribution):
        return dist.proba_distribution(params, policy.log_std)
    return dist.proba_distribution(action_logits=params)
