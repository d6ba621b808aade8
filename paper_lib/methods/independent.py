"""Independently trained ensembles (paper appendix B.2) as one SB3 policy, assembled with no retraining.

k baseline agents, each trained alone with its own seed (and, where the env normalizes
observations, its own `VecNormalize` statistics), become one `IndependentEnsemblePolicy`. It is
a `MemberActorCriticPolicy` whose k members are the trained SB3 policies themselves, so every
consumer of member policies takes it unchanged: `predict` with vote / average / single
inference (through `combine_actions`), `member_outputs`, `uncertainty`, `act_with_uncertainty`,
`policy_features`, the OOD collection and scoring, and the reward evaluation.

**It takes RAW observations.** Member j applies its own normalizer (mean, variance, epsilon and
clip of its `VecNormalize`, computed in float64 exactly as `VecNormalize.normalize_obs` does) to
the raw observation before its network; members trained without normalization see the raw
observation. So run it in a plain env (no `VecNormalize`), and collect or score raw states.

    model = assemble_ensemble([m0, m1, m2, m3])          # trained baseline SB3 models
    model.save("ensemble.zip")
    model = PPO.load("ensemble.zip")                     # plain SB3 loading works (or load_independent_ensemble)
    model.policy.set_inference("single", member=2)

Members run one after the other (a loop over k SB3 policies), not as one batched pass like the
member methods: they are separate networks that were never meant to be batched. Continuous
actions: `single` samples with that member's own action std; `vote` / `average` sample around
the members' mean action with the geometric mean of their stds (`log_std` = mean of the
members' log_std), since the members never agreed on a shared std. The assembled policy is for
inference only: training it further raises an error (train the members instead).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import VecNormalize
from torch import nn

from paper_lib.methods.networks import to_members
from paper_lib.methods.policy import MemberActorCriticPolicy, combine_actions

#: Constructor arguments of a member's policy that the ensemble supplies itself.
_SUPPLIED = ("observation_space", "action_space", "lr_schedule")


class RawObservation(BaseFeaturesExtractor):
    """Hands the raw observation tensor on: each member preprocesses (and normalizes) it itself."""

    def __init__(self, observation_space: spaces.Space):
        super().__init__(observation_space, features_dim=int(np.prod(observation_space.shape)))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return observations


class _Tower:
    """What `uncertainty.policy_features` reads from a member network: `policy_tower[:-1]`, the
    map from (k, N, ...) observations to the members' last hidden layers (k, N, H)."""

    def __init__(self, net: IndependentMembers):
        self.net = net

    def __getitem__(self, item: slice):
        if item != slice(None, -1):
            raise TypeError("an independent ensemble's policy tower offers only [:-1] (the last hidden layers)")
        return self.net.last_hidden


class IndependentMembers(nn.Module):
    """The k trained SB3 policies and their observation normalizers, behind the member-network interface.

    `members(obs, "all")` gives (k, N, A) action parameters and (k, N, 1) values; "split" sends
    consecutive chunk j of the batch through member j, as the member networks do.
    """

    def __init__(self, members: list[ActorCriticPolicy], normalize_obs: bool, obs_shape: tuple[int, ...]):
        super().__init__()
        self.nets = nn.ModuleList(members)
        self.k = len(members)
        self.normalize_obs = normalize_obs
        action_space = members[0].action_space
        self.latent_dim_pi = int(action_space.n) if isinstance(action_space, spaces.Discrete) else int(
            np.prod(action_space.shape))
        self.latent_dim_vf = 1
        shape = (self.k, *obs_shape) if normalize_obs else (0,)
        # float64 like VecNormalize's statistics, so the normalized observation is bit-identical
        self.register_buffer("obs_mean", th.zeros(shape, dtype=th.float64))
        self.register_buffer("obs_var", th.ones(shape, dtype=th.float64))
        self.register_buffer("obs_epsilon", th.full((self.k if normalize_obs else 0,), 1e-8, dtype=th.float64))
        self.register_buffer("obs_clip", th.full((self.k if normalize_obs else 0,), 10.0, dtype=th.float64))

    def set_normalizer(self, j: int, normalizer: VecNormalize) -> None:
        """Copy member j's observation statistics (its VecNormalize) into the ensemble."""
        self.obs_mean[j] = th.as_tensor(normalizer.obs_rms.mean, dtype=th.float64)
        self.obs_var[j] = th.as_tensor(normalizer.obs_rms.var, dtype=th.float64)
        self.obs_epsilon[j] = float(normalizer.epsilon)
        self.obs_clip[j] = float(normalizer.clip_obs)

    def observation_for(self, j: int, obs: th.Tensor) -> th.Tensor:
        """The raw observation as member j saw observations in training (VecNormalize.normalize_obs in torch)."""
        if not self.normalize_obs:
            return obs
        x = (obs.to(th.float64) - self.obs_mean[j]) / th.sqrt(self.obs_var[j] + self.obs_epsilon[j])
        return x.clamp(-self.obs_clip[j], self.obs_clip[j]).to(th.float32)

    def _latents(self, j: int, obs: th.Tensor, actor: bool, critic: bool):
        net = self.nets[j]
        features = net.extract_features(self.observation_for(j, obs))
        pi_features, vf_features = (features, features) if net.share_features_extractor else features
        latent_pi = net.mlp_extractor.forward_actor(pi_features) if actor else None
        latent_vf = net.mlp_extractor.forward_critic(vf_features) if critic else None
        return latent_pi, latent_vf

    def member(self, j: int, obs: th.Tensor, actor: bool = True, critic: bool = True):
        """Member j on raw observations (N, ...): its action parameters (N, A) and value (N, 1)."""
        latent_pi, latent_vf = self._latents(j, obs, actor, critic)
        net = self.nets[j]
        return (net.action_net(latent_pi) if actor else None), (net.value_net(latent_vf) if critic else None)

    def members(self, obs: th.Tensor, layout: str, actor: bool = True, critic: bool = True):
        x = to_members(obs, self.k, layout)
        outs = [self.member(j, x[j], actor, critic) for j in range(self.k)]
        pi = th.stack([o[0] for o in outs]) if actor else None
        vf = th.stack([o[1] for o in outs]) if critic else None
        return pi, vf

    def last_hidden(self, x: th.Tensor) -> th.Tensor:
        """(k, N, ...) observations -> (k, N, H): each member's last hidden layer on its row block."""
        return th.stack([self._latents(j, x[j], True, False)[0] for j in range(self.k)])

    @property
    def policy_tower(self) -> _Tower:
        return _Tower(self)

    def forward(self, obs: th.Tensor):
        raise _not_trainable()

    def forward_actor(self, obs: th.Tensor):
        raise _not_trainable()

    def forward_critic(self, obs: th.Tensor):
        raise _not_trainable()


def _not_trainable() -> ValueError:
    return ValueError("an IndependentEnsemblePolicy is assembled from separately trained baseline agents and is "
                      "not trained further; train the members (paper_lib.agents.training ... baseline SEED) and assemble again")


class _MemberStd:
    """What `combine_actions` reads from a policy, with one member's own action std."""

    def __init__(self, action_dist, log_std: th.Tensor):
        self.action_dist, self.log_std = action_dist, log_std


class IndependentEnsemblePolicy(MemberActorCriticPolicy):
    """k separately trained baseline policies as one member policy (paper appendix B.2).

    :param member_kwargs: the members' SB3 constructor arguments (same architecture for all)
    :param n_members: k
    :param normalize_obs: whether the members were trained on VecNormalize-d observations;
        each member then keeps its own statistics (buffers of this policy)
    :param member_seeds: the members' training seeds (for the record)
    """

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space, lr_schedule,
                 member_kwargs: dict[str, Any], n_members: int = 4, normalize_obs: bool = False,
                 member_seeds: Sequence[int] = (), inference: str = "vote", inference_member: int | None = None,
                 **kwargs: Any):
        self.member_kwargs = {k: v for k, v in dict(member_kwargs).items() if k not in _SUPPLIED}
        self.normalize_obs = bool(normalize_obs)
        self.member_seeds = [int(s) for s in member_seeds]
        for key in ("method", "hidden_sizes", "dropout_p", "masksembles_scale", "member_seed", "net_arch",
                    "activation_fn", "features_extractor_class", "features_extractor_kwargs", "ortho_init"):
            kwargs.pop(key, None)  # the members carry their own architecture
        super().__init__(observation_space, action_space, lr_schedule, method="ensemble", n_members=n_members,
                         hidden_sizes=(), inference=inference, inference_member=inference_member,
                         features_extractor_class=RawObservation, ortho_init=False, **kwargs)

    def _build_mlp_extractor(self) -> None:
        # ortho_init off: the weights come from the trained members, an initialization would be thrown away
        members = [ActorCriticPolicy(self.observation_space, self.action_space, self._dummy_schedule,
                                     **{**self.member_kwargs, "ortho_init": False}) for _ in range(self.n_members)]
        self.mlp_extractor = IndependentMembers(members, self.normalize_obs, self.observation_space.shape)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = ActorCriticPolicy._get_constructor_parameters(self)
        for key in ("net_arch", "activation_fn", "features_extractor_class", "features_extractor_kwargs", "ortho_init"):
            data.pop(key, None)
        data.update(member_kwargs=self.member_kwargs, n_members=self.n_members, normalize_obs=self.normalize_obs,
                    member_seeds=self.member_seeds)
        return data

    def extract_features(self, obs, features_extractor=None):
        """The raw observation: each member preprocesses and normalizes it itself."""
        return obs

    # --- the member-output interface ---------------------------------------------------------
    def member_outputs_from_tensor(self, obs: th.Tensor, state_seeds: np.ndarray | None = None, *,
                                   actor: bool = True, critic: bool = True, path: str = "exact"
                                   ) -> tuple[th.Tensor | None, th.Tensor | None]:
        """All k members on every raw state: (k, N, A) action params and (k, N) values (None where not asked).

        `state_seeds` and `path` are accepted for the member-policy interface; trained baselines sample nothing
        and run their own SB3 modules.
        """
        pi, vf = self.mlp_extractor.members(obs, "all", actor=actor, critic=critic)
        return pi, (None if vf is None else vf.squeeze(-1))

    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        mode, member = self.inference
        if mode == "single":  # only the chosen member runs (the same member combine_actions would pick)
            m = int(th.randint(self.n_members, ())) if member is None else member
            pi = self.mlp_extractor.member(m, observation, critic=False)[0][None]
            own = _MemberStd(self.action_dist, self.mlp_extractor.nets[m].log_std) if isinstance(
                self.action_space, spaces.Box) else self
            return combine_actions(pi, own, "single", 0, deterministic)
        pi, _ = self.mlp_extractor.members(observation, "all", critic=False)
        return combine_actions(pi, self, mode, member, deterministic, **self.inference_options)

    # --- not trainable -------------------------------------------------------------------------
    def forward(self, obs: th.Tensor, deterministic: bool = False):
        raise _not_trainable()

    def evaluate_actions(self, obs, actions):
        raise _not_trainable()

    def predict_values(self, obs: th.Tensor) -> th.Tensor:
        raise _not_trainable()


def _member_normalizer(model: BaseAlgorithm, normalizer: VecNormalize | None, j: int) -> VecNormalize | None:
    normalizer = normalizer if normalizer is not None else model.get_vec_normalize_env()
    trained_with = bool((getattr(model, "paper_lib_config", None) or {}).get("normalize_obs"))
    if normalizer is None and trained_with:
        raise ValueError(f"member {j} was trained on VecNormalize-d observations but no normalizer was given; pass "
                         "normalizers=[VecNormalize.load(path, venv) or the pickled VecNormalize, ...] in member order")
    if normalizer is not None and not isinstance(normalizer, VecNormalize):
        raise ValueError(f"normalizers[{j}] is a {type(normalizer).__name__}; give the member's VecNormalize or None")
    if normalizer is not None and not normalizer.norm_obs:
        return None
    return normalizer


def same_parameters(a: ActorCriticPolicy, b: ActorCriticPolicy) -> bool:
    """Whether two policies hold equal parameters (and buffers): the same agent, however it was loaded."""
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(
        sa[key].shape == sb[key].shape and th.equal(sa[key].cpu(), sb[key].cpu()) for key in sa)


def check_distinct_members(members: Sequence[BaseAlgorithm]) -> None:
    """Refuse a member given twice: identical members agree everywhere, so every spread (value_std, ...) is 0."""
    for j in range(1, len(members)):
        for i in range(j):
            if members[i] is members[j] or same_parameters(members[i].policy, members[j].policy):
                raise ValueError(f"members {i} and {j} have identical parameters, got the same agent twice; an "
                                 "ensemble of copies reports zero uncertainty (value_std 0): assemble separately "
                                 "trained agents (different seeds)")


def assemble_ensemble(members: Sequence[BaseAlgorithm], normalizers: Sequence[VecNormalize | None] | None = None,
                      inference: str = "vote", member_seeds: Sequence[int] | None = None,
                      config: dict[str, Any] | None = None) -> PPO:
    """One PPO model whose policy is the k trained baseline `members`, unchanged (no retraining).

    `normalizers[j]` is member j's VecNormalize (None: the one its model holds, if any). All
    members must be plain actor-critic policies of the same architecture on the same spaces, and
    either all or none normalized. `config` is kept as `model.paper_lib_config` (saved with it).
    """
    members = list(members)
    if len(members) < 2:
        raise ValueError(f"an ensemble needs at least 2 members, got {len(members)}")
    normalizers = list(normalizers) if normalizers is not None else [None] * len(members)
    if len(normalizers) != len(members):
        raise ValueError(f"got {len(normalizers)} normalizers for {len(members)} members; give one per member "
                         "(or None)")
    first = members[0].policy
    reference = {k: v for k, v in first._get_constructor_parameters().items() if k not in _SUPPLIED}
    for j, model in enumerate(members):
        policy = model.policy
        if isinstance(policy, MemberActorCriticPolicy) or not isinstance(policy, ActorCriticPolicy):
            raise ValueError(f"member {j} has a {type(policy).__name__}; an independent ensemble is made of baseline "
                             "agents (MlpPolicy / CnnPolicy), e.g. trained with method='baseline'")
        if policy.observation_space != first.observation_space or policy.action_space != first.action_space:
            raise ValueError(f"member {j} acts on {policy.observation_space} -> {policy.action_space} but member 0 on "
                             f"{first.observation_space} -> {first.action_space}; assemble members of one env")
        params = {k: v for k, v in policy._get_constructor_parameters().items() if k not in _SUPPLIED}
        if params != reference:
            diff = sorted(k for k in set(params) | set(reference) if params.get(k) != reference.get(k))
            raise ValueError(f"member {j} differs from member 0 in {diff}; assemble members trained with one recipe")
    resolved = [_member_normalizer(m, n, j) for j, (m, n) in enumerate(zip(members, normalizers))]
    normalized = [n is not None for n in resolved]
    if any(normalized) and not all(normalized):
        raise ValueError(f"members {[j for j, n in enumerate(normalized) if n]} normalize observations and the others "
                         "do not; assemble members trained with one recipe")
    check_distinct_members(members)
    seeds = list(member_seeds) if member_seeds is not None else [m.seed for m in members]
    policy_kwargs = dict(member_kwargs=reference, n_members=len(members), normalize_obs=all(normalized),
                         member_seeds=[int(s) if s is not None else -1 for s in seeds], inference=inference)
    model = PPO(IndependentEnsemblePolicy, env=None, n_steps=2, batch_size=2, policy_kwargs=policy_kwargs,
                device="cpu", _init_setup_model=False)
    model.observation_space, model.action_space, model.n_envs = first.observation_space, first.action_space, 1
    model._setup_model()
    net: IndependentMembers = model.policy.mlp_extractor
    for j, member in enumerate(members):
        net.nets[j].load_state_dict(member.policy.state_dict())
        if resolved[j] is not None:
            net.set_normalizer(j, resolved[j])
    if isinstance(first.action_space, spaces.Box):
        with th.no_grad():
            model.policy.log_std.copy_(th.stack([m.policy.log_std.detach().cpu() for m in members]).mean(0))
    model.policy.set_training_mode(False)
    model.paper_lib_config = dict(config or {})
    return model


def load_independent_ensemble(path: str | Path, device: str = "cpu") -> PPO:
    """Load a saved assembled ensemble (the same as `PPO.load`, with a check of what was loaded)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found; save an assembled ensemble with model.save({str(path)!r})")
    model = PPO.load(path, device=device)
    if not isinstance(model.policy, IndependentEnsemblePolicy):
        raise ValueError(f"{path} holds a {type(model.policy).__name__}, not an assembled independent ensemble; "
                         "load it with PPO.load, or assemble one with assemble_ensemble")
    return model
