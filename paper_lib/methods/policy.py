"""The SB3 policy: one ActorCriticPolicy subclass for every member method.

SB3's own `forward`, `evaluate_actions`, `get_distribution` and `predict_values` run
unchanged on the member network in the *split* layout (chunk j of a batch -> member j), which
is exactly what rollouts (env group j acts with member j) and the shared-buffer update need.
This class only adds what SB3 cannot know about:
- `_predict` combines the members (vote / average) or uses a single one (paper section 4.2);
- a truncated episode's bootstrap value comes from the member of that episode's env group,
  which `MemberGroupVecEnv` tags onto the terminal observation;
- `member_outputs` returns all k members' raw outputs for uncertainty and analysis.

The inference paths (`_predict`, `member_outputs_from_tensor`) draw MC masks per (member,
state) and run through the lean `paper_lib.methods.inference` (same numbers as the member
network's modules, less work); the training paths (`forward`, `evaluate_actions`, the tagged
`predict_values`) keep one mask per member per pass and run the modules themselves, so
training numerics do not depend on the inference code.
"""

from __future__ import annotations

import contextlib
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import CategoricalDistribution, DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.preprocessing import is_image_space
from torch import nn

from paper_lib.methods import inference as lean
from paper_lib.methods.groups import GROUPS_TAG, MEMBER_TAG
from paper_lib.methods.layers import has_stochastic_layers, per_state_masks
from paper_lib.methods.networks import MemberActorCritic, MemberMLP, MemberNatureCNN, MemberSpec

INFERENCE_MODES = ("vote", "average", "single")
#: How a deterministic vote picks among actions with equally many votes: the tied action with
#: the highest averaged probability (repeatable; default), or one at random (the paper's text).
TIE_RULES = ("mean_prob", "random")
#: What a sampled (deterministic=False) discrete vote does: sample from the members' averaged
#: distribution (the paper's Table 1; default), or take the majority of each member's own sample.
VOTE_SAMPLING = ("average", "member_votes")
#: The buffers that hold the inference settings (saved with the model), in `_inference_settings`' order.
_INFERENCE_BUFFERS = ("_inference_mode", "_inference_member", "_inference_ties", "_inference_vote_sampling")
#: Largest per-state seed; seeds are drawn from torch's RNG (or a seeded generator) below it.
_SEED_BOUND = 2**62
#: The largest float32: the networks compute in float32, so a wider float beyond it becomes inf there.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def all_finite(obs: np.ndarray) -> bool:
    """Whether every value stays finite as the float32 the networks compute in (one pass: `predict` runs it).

    Integer dtypes (images) are always finite; a float64 beyond FLOAT32_MAX is not (inf once cast).
    """
    if obs.dtype.kind != "f" or obs.size == 0:
        return True
    if obs.dtype.itemsize <= 4:
        return bool(np.isfinite(obs).all())
    return bool(np.abs(obs).max() <= FLOAT32_MAX)  # False for NaN as well


def check_finite(obs: np.ndarray, batched: bool = True, what: str = "observations") -> None:
    """One ValueError naming how many states hold NaN or inf (as float32); the networks would return NaN."""
    if all_finite(obs):
        return
    rows = obs.reshape(len(obs), -1) if batched and obs.ndim > 0 else obs.reshape(1, -1)
    bad = int((~(np.abs(rows) <= FLOAT32_MAX)).any(axis=1).sum())
    raise ValueError(f"{what} hold NaN or inf in {bad} of {len(rows)} states (a float beyond float32's range, "
                     "|x| > 3.4e38, is inf to the network); drop or fix those states first")


def draw_state_seeds(n: int, generator: th.Generator | None = None) -> np.ndarray:
    """One seed per state for `per_state_masks`, from torch's global RNG unless a generator is given."""
    return th.randint(0, _SEED_BOUND, (n,), generator=generator).numpy()


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
    :param inference_ties: a deterministic vote's tie rule, one of TIE_RULES
    :param inference_vote_sampling: a sampled discrete vote's rule, one of VOTE_SAMPLING
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
        inference_ties: str = "mean_prob",
        inference_vote_sampling: str = "average",
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
        self.register_buffer("_inference_ties", th.tensor(0))
        self.register_buffer("_inference_vote_sampling", th.tensor(0))
        # checkpoints saved before the last two buffers existed load with the defaults
        self.register_load_state_dict_pre_hook(_default_inference_options)
        self.set_inference(inference, inference_member, ties=inference_ties, vote_sampling=inference_vote_sampling)

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
    def set_inference(self, mode: str, member: int | None = None, *, ties: str | None = None,
                      vote_sampling: str | None = None) -> None:
        """Choose how `predict` turns k members into one action; saved with the model.

        `ties` (TIE_RULES) and `vote_sampling` (VOTE_SAMPLING) refine discrete `vote`; None
        keeps their current setting.
        """
        if mode not in INFERENCE_MODES:
            raise ValueError(f"unknown inference mode {mode!r}; use one of {INFERENCE_MODES}")
        member = self._checked_member(mode, member)
        if ties is not None and ties not in TIE_RULES:
            raise ValueError(f"unknown tie rule {ties!r}; use one of {TIE_RULES}")
        if vote_sampling is not None and vote_sampling not in VOTE_SAMPLING:
            raise ValueError(f"unknown vote sampling {vote_sampling!r}; use one of {VOTE_SAMPLING}")
        self._inference_mode.fill_(INFERENCE_MODES.index(mode))
        self._inference_member.fill_(-1 if member is None else member)
        if ties is not None:
            self._inference_ties.fill_(TIE_RULES.index(ties))
        if vote_sampling is not None:
            self._inference_vote_sampling.fill_(VOTE_SAMPLING.index(vote_sampling))

    def _checked_member(self, mode: str, member: Any) -> int | None:
        """`member` as an int in [0, k) for "single" (or None: a random member); only "single" takes one,
        so a member given with vote / average would be silently ignored."""
        if member is None:
            return None
        if mode != "single":
            raise ValueError(f"inference mode {mode!r} combines all members and takes no member, got "
                             f"member={member!r}; drop member= or use set_inference('single', member={member!r})")
        if isinstance(member, bool) or not isinstance(member, (int, np.integer)):
            raise ValueError(f"inference member must be an integer index in [0, {self.n_members - 1}], got "
                             f"{member!r}; pass e.g. member=0")
        if not 0 <= member < self.n_members:
            raise ValueError(f"inference_member={member} is not in [0, {self.n_members - 1}]; this policy has "
                             f"k={self.n_members} members")
        return int(member)

    @property
    def inference(self) -> tuple[str, int | None]:
        return self._inference_settings()[0]

    @property
    def inference_options(self) -> dict[str, str]:
        """The discrete vote's tie rule and sampling rule, as `combine_actions` takes them."""
        return dict(self._inference_settings()[1])

    def _inference_settings(self) -> tuple[tuple[str, int | None], dict[str, str]]:
        """(mode, member) and the options, read from the buffers again only when one changed (set_inference,
        load_state_dict): four int() reads of tensors cost as much as a layer of a one-state pass."""
        buffers = tuple(self._buffers[name] for name in _INFERENCE_BUFFERS)
        key = tuple((b.data_ptr(), b._version) for b in buffers)
        cached = self.__dict__.get("_inference_cache")
        if cached is None or cached[0] != key:
            mode, member = INFERENCE_MODES[int(buffers[0])], int(buffers[1])
            settings = ((mode, None if member < 0 or mode != "single" else member),  # only "single" uses a member
                        {"ties": TIE_RULES[int(buffers[2])], "vote_sampling": VOTE_SAMPLING[int(buffers[3])]})
            cached = self.__dict__["_inference_cache"] = (key, buffers, settings)
        return cached[2]

    # --- member outputs ------------------------------------------------------------------
    def member_outputs_from_tensor(self, obs: th.Tensor, state_seeds: np.ndarray | None = None, *,
                                   actor: bool = True, critic: bool = True, path: str = "exact"
                                   ) -> tuple[th.Tensor | None, th.Tensor | None]:
        """All k members on every state, one batched pass: (k, N, A) action params and (k, N) values.

        MC methods draw their masks per (member, state), from `state_seeds` (one per state) or,
        when None, from seeds drawn from torch's RNG. `actor` / `critic` False skip that output
        (None). Without autograd this runs the lean inference path (`path`: "exact" or "fast",
        `inference.PATHS`), else the modules themselves.
        """
        seeds = self.state_seeds(obs.shape[0], state_seeds)
        pi, vf = lean.members(self, obs, seeds, actor=actor, critic=critic, path=path)
        return pi, (None if vf is None else vf.squeeze(-1))

    def last_hidden_from_tensor(self, obs: th.Tensor, state_seeds: np.ndarray | None = None, path: str = "exact"
                                ) -> th.Tensor:
        """(k, N, H): every member's last hidden layer (the action head's input), masks drawn as above."""
        return lean.last_hidden_members(self, obs, self.state_seeds(obs.shape[0], state_seeds), path)

    @property
    def samples_members(self) -> bool:
        """Whether the members are MC samples (MC Dropout / DropConnect), so outputs depend on a seed."""
        cached = self.__dict__.get("_samples_members")  # the network's layers never change after building
        if cached is None:
            cached = self.__dict__["_samples_members"] = has_stochastic_layers(self.mlp_extractor)
        return cached

    def state_seeds(self, n_states: int, state_seeds: np.ndarray | None = None) -> np.ndarray | None:
        """The per-state seeds MC layers sample from (drawn from torch's RNG when None); None without MC layers."""
        if not self.samples_members:
            return None
        return draw_state_seeds(n_states) if state_seeds is None else state_seeds

    def per_state_masks(self, n_states: int, state_seeds: np.ndarray | None = None):
        """Context in which the member network samples per (member, state); nothing to do without MC layers."""
        if not self.samples_members:
            return contextlib.nullcontext()
        return per_state_masks(self.mlp_extractor, draw_state_seeds(n_states) if state_seeds is None else state_seeds)

    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        # "fast": on fewer than COMPACT_MIN_STATES states (acting in envs) it is the exact path, bit for bit
        pi, _ = self.member_outputs_from_tensor(observation, critic=False, path="fast")
        return combine_actions(pi, self, *self.inference, deterministic=deterministic, **self.inference_options)

    def set_training_mode(self, mode: bool) -> None:
        """SB3's, skipped when nothing changes: `predict` calls it every time, and walking every
        module costs as much as a one-state forward pass. The flag changes no number here."""
        if mode != self.training or mode != self.mlp_extractor.training:
            super().set_training_mode(mode)

    # --- truncated-episode bootstrap ----------------------------------------------------
    def obs_to_tensor(self, observation):
        """SB3's, refusing non-finite states (`predict` would return NaN actions) and keeping a member tag."""
        array = observation if isinstance(observation, np.ndarray) else (
            np.asarray(observation) if isinstance(observation, (list, tuple)) else None)
        if array is not None and not all_finite(array):
            check_finite(array, batched=array.ndim > len(self.observation_space.shape or ()))
        member = getattr(observation, MEMBER_TAG, None)
        tensor, vectorized = super().obs_to_tensor(observation)
        if member is not None:
            setattr(tensor, MEMBER_TAG, member)
            setattr(tensor, GROUPS_TAG, getattr(observation, GROUPS_TAG, None))
        return tensor, vectorized

    def predict_values(self, obs: th.Tensor) -> th.Tensor:
        member = getattr(obs, MEMBER_TAG, None)
        if member is None:
            return super().predict_values(obs)
        self._check_groups(getattr(obs, GROUPS_TAG, None))
        features = super(ActorCriticPolicy, self).extract_features(obs, self.vf_features_extractor)
        _, vf = self.mlp_extractor.members(features, "all", actor=False)
        return vf[member]

    def _check_groups(self, n_groups: int | None) -> None:
        """A MemberGroupVecEnv made for another k tags episodes with the wrong members; refuse it."""
        if n_groups is not None and n_groups != self.n_members:
            raise ValueError(f"the env's MemberGroupVecEnv splits its envs into {n_groups} member groups, got a "
                             f"policy with k={self.n_members} members; wrap the env with "
                             f"MemberGroupVecEnv(venv, {self.n_members}) (make_agent does)")


def combine_actions(pi: th.Tensor, policy: ActorCriticPolicy, mode: str, member: int | None,
                    deterministic: bool, ties: str = "mean_prob", vote_sampling: str = "average") -> th.Tensor:
    """Turn the k members' action parameters (k, N, A) into N actions (paper section 4.2).

    Continuous actions (vote and average alike): the mean of the members' means, or a sample
    around it with the policy's std. Discrete `average`: the argmax of, or a sample from, the
    averaged distribution. Discrete `vote`, deterministic: the majority of the members' argmax
    actions, ties broken by `ties`; sampled: a sample from the averaged distribution (the
    paper's Table 1), or with vote_sampling="member_votes" the majority of each member's sample.
    """
    dist = policy.action_dist
    if mode == "single":
        m = int(th.randint(pi.shape[0], ())) if member is None else member
        return _mode(dist, pi[m]) if deterministic else _distribution(dist, pi[m], policy).get_actions()
    if isinstance(dist, DiagGaussianDistribution):  # continuous: vote and average both average the means
        mean = pi.mean(0)
        return mean if deterministic else _distribution(dist, mean, policy).get_actions()
    assert isinstance(dist, CategoricalDistribution)
    probs = th.softmax(pi, -1).mean(0)
    if mode == "average" or (not deterministic and vote_sampling == "average"):
        return probs.argmax(-1) if deterministic else th.multinomial(probs, 1).squeeze(-1)
    member_actions = pi.argmax(-1) if deterministic else th.distributions.Categorical(logits=pi).sample()
    counts = nn.functional.one_hot(member_actions, pi.shape[-1]).sum(0).float()
    if ties == "random":
        return (counts + 0.5 * th.rand_like(counts)).argmax(-1)
    tied = counts == counts.max(-1, keepdim=True).values
    return th.where(tied, probs, th.full_like(probs, -1.0)).argmax(-1)  # the tied action most probable on average


def _default_inference_options(module: nn.Module, state_dict: dict, prefix: str, *args: Any) -> None:
    """Load-time hook: a checkpoint from before the tie and vote-sampling options gets their defaults."""
    for name in ("_inference_ties", "_inference_vote_sampling"):
        state_dict.setdefault(prefix + name, th.tensor(0))


def _mode(dist, params: th.Tensor) -> th.Tensor:
    """SB3's deterministic action without building a distribution: the Gaussian's mean, or the
    argmax of torch Categorical's probabilities (softmax of the normalized logits, as SB3 takes it)."""
    if isinstance(dist, DiagGaussianDistribution):
        return params
    return th.softmax(params - params.logsumexp(-1, keepdim=True), -1).argmax(-1)


def _distribution(dist, params: th.Tensor, policy: ActorCriticPolicy):
    if isinstance(dist, DiagGaussianDistribution):
        return dist.proba_distribution(params, policy.log_std)
    return dist.proba_distribution(action_logits=params)
