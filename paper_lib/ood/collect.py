"""Collect the benchmark's ID and OOD states by letting a trained agent act (paper section 5, appendix G).

Protocol (one loop for ID and OOD, so the two samples are comparable by construction):
- every episode runs in a fresh env; at most ``max_episode_steps`` states per episode
  (s_0 = the reset observation ... s_{T-1}; a terminal observation is never kept);
- the first ``skip_first`` states of every episode are dropped: perturbed physics acts
  only once the agent moves, so early OOD states look like ID ones (appendix G);
- main-text protocol (section 5, the default): ``configs=50, steps_per_config=100``, each
  configuration gives exactly ``steps_per_config`` states (restarting inside the same
  configuration if an episode ends early), 50 x 100 = 5000 states; ID states likewise:
  ``episodes=20, steps_per_episode=100``, each from a fresh env seed (``ID_MAIN_PROTOCOL``).
  Many short clusters are what lets a cluster bootstrap give a useful interval;
- appendix G's protocol (pass ``n_states``): a NEW configuration (ID: env seed) at every
  restart (episode end or step limit), until ``n_states`` states.

The agent acts with one ``ActionMode`` (deterministic or sampled; how members combine),
applied to the policy and recorded in the dataset's metadata. A configuration whose rollout
goes NaN/inf (or MuJoCo flags it unstable), or whose episodes end before ``skip_first``
``MAX_EMPTY_PER_CONFIG`` times in a row (nothing to keep), is reported with a warning, its states are
discarded and a new configuration is drawn; both count in ``n_rejected_configs``. Seeds: one numpy Generator drives every
configuration and env seed, and torch's RNG (sampled actions, random members) is seeded in
a forked RNG state, so the same seed gives the same states without touching global state.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pandas as pd
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecFrameStack, VecNormalize

from paper_lib.agents.envs import N_STACK, is_atari, make_single_env, register_atari
from paper_lib.methods.policy import INFERENCE_MODES, MemberActorCriticPolicy
from paper_lib.ood.atari import (
    ATARI_GAMES,
    DEFAULT_SOURCE,
    env_id as atari_env_id,
    game_of,
    indicator_name,
    make_atari_env_single,
    make_ood_atari_env,
    read_indicator,
    sample_atari_config,
    source_values,
)
from paper_lib.ood.datasets import ID_LABEL, ID_SOURCE, NO_CONFIG, OOD_LABEL, StateDataset
from paper_lib.ood.mujoco import (
    SUPPORTED_ENVS,
    PerturbationRanges,
    UnstablePerturbationWarning,
    is_unstable,
    make_perturbed_env,
    sample_stable_config,
)
from paper_lib.ood.pixels import PIXEL_PERTURBATIONS, noise_ood, perturb_pixels

#: The main text's OOD protocol (the default): ``collect_mujoco_ood_states(..., **MAIN_TEXT_PROTOCOL)``.
MAIN_TEXT_PROTOCOL: dict[str, int] = {"configs": 50, "steps_per_config": 100}
#: Its ID counterpart (the default of ``collect_id_states``): as many states per episode as per configuration.
ID_MAIN_PROTOCOL: dict[str, int] = {"episodes": 20, "steps_per_episode": 100}
#: Give up after this many configurations in a row went unstable (the ranges are too wide).
MAX_UNSTABLE_IN_A_ROW = 20
#: Reject a configuration whose episodes end before ``skip_first`` this many times in a row: the
#: perturbation ends every episode at once (e.g. Ant flipped by 40x friction), so it yields no states.
#: (Before this rule, 100 in a row raised; so no dataset collected before it changes.)
MAX_EMPTY_PER_CONFIG = 100
#: Give up after this many episodes in a row, over configurations, ended before ``skip_first``.
MAX_EMPTY_IN_A_ROW = 1000
_MUJOCO_INSTABILITY = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                       mujoco.mjtWarning.mjWARN_BADQACC)


# ------------------------------------------------------------------------------ action mode


@dataclass(frozen=True)
class ActionMode:
    """How the agent picks actions while states are collected (paper Table 2 uses sampling + average).

    ``inference`` and ``member`` only act on member policies (a baseline has one network);
    ``member`` picks the network of ``inference="single"`` (None: a random one per step).
    """

    deterministic: bool
    inference: str = "average"
    member: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.deterministic, (bool, np.bool_)):
            raise ValueError(f"ActionMode.deterministic={self.deterministic!r}: give True (mean / argmax action) "
                             "or False (sampled action).")
        object.__setattr__(self, "deterministic", bool(self.deterministic))
        if self.inference not in INFERENCE_MODES:
            raise ValueError(f"ActionMode.inference={self.inference!r}: use one of {INFERENCE_MODES}.")
        if self.member is not None:
            if self.inference != "single":
                raise ValueError(f"ActionMode.member={self.member} only applies to inference='single'; "
                                 f"drop it or set inference='single'.")
            if isinstance(self.member, bool) or not isinstance(self.member, (int, np.integer)) or self.member < 0:
                raise ValueError(f"ActionMode.member={self.member!r}: give a member index >= 0 or None.")
            object.__setattr__(self, "member", int(self.member))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def apply(self, policy: BasePolicy) -> str:
        """Set the inference mode on a member policy (it stays set); returns "members" or "baseline"."""
        if isinstance(policy, MemberActorCriticPolicy):
            policy.set_inference(self.inference, self.member)
            return "members"
        if self.member is not None:
            raise ValueError(f"ActionMode(member={self.member}) asks for one member, but this {type(policy).__name__} "
                             "has no members (baseline); use member=None.")
        return "baseline"


# ----------------------------------------------------------------------------- the agent


def policy_of(model_or_policy: BaseAlgorithm | BasePolicy) -> BasePolicy:
    if isinstance(model_or_policy, BaseAlgorithm):
        return model_or_policy.policy
    if isinstance(model_or_policy, BasePolicy):
        return model_or_policy
    raise TypeError(f"expected an SB3 model or policy, got {type(model_or_policy).__name__}.")


def needs_normalization(model_or_policy: BaseAlgorithm | BasePolicy) -> bool:
    """Whether the model says it was trained on VecNormalize-d observations."""
    if not isinstance(model_or_policy, BaseAlgorithm):
        return False
    config = getattr(model_or_policy, "paper_lib_config", {}) or {}
    return bool(config.get("normalize_obs")) or model_or_policy.get_vec_normalize_env() is not None


class _Actor:
    """The policy acting on (normalized, if need be) observations of a one-env VecEnv."""

    def __init__(self, policy: BasePolicy, action_mode: ActionMode, vecnormalize: VecNormalize | None):
        self.policy, self.deterministic, self.vecnormalize = policy, action_mode.deterministic, vecnormalize

    def policy_obs(self, obs: np.ndarray) -> np.ndarray:
        return obs if self.vecnormalize is None else self.vecnormalize.normalize_obs(obs)

    def act(self, policy_obs: np.ndarray) -> np.ndarray:
        return self.policy.predict(policy_obs, deterministic=self.deterministic)[0]


def _prepare(model: BaseAlgorithm | BasePolicy, env_id: str, n_states: int, action_mode: ActionMode, seed: int,
             max_episode_steps: int, skip_first: int, vecnormalize: VecNormalize | None) -> tuple[_Actor, str]:
    """Check every common argument where it enters; apply the action mode. Returns (actor, policy kind)."""
    policy = policy_of(model)
    if isinstance(n_states, bool) or not isinstance(n_states, (int, np.integer)) or n_states <= 0:
        raise ValueError(f"n_states={n_states!r}: need a positive number of states (the paper uses 2000).")
    if not isinstance(action_mode, ActionMode):
        raise TypeError(f"action_mode must be an ActionMode (e.g. ActionMode(deterministic=False)), "
                        f"got {type(action_mode).__name__}.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r}: need a non-negative int.")
    if not (isinstance(skip_first, (int, np.integer)) and isinstance(max_episode_steps, (int, np.integer))
            and 0 <= skip_first < max_episode_steps):
        raise ValueError(f"skip_first={skip_first!r}, max_episode_steps={max_episode_steps!r}: need "
                         "0 <= skip_first < max_episode_steps (the paper: 10 and 500).")
    trained_on = (getattr(model, "paper_lib_config", None) or {}).get("env_id")
    if trained_on is not None and trained_on != env_id:
        raise ValueError(f"the model was trained on {trained_on} but env_id={env_id!r}: collect in its own env.")
    if vecnormalize is not None:
        if not isinstance(vecnormalize, VecNormalize):
            raise TypeError(f"vecnormalize must be the VecNormalize the model was trained with, "
                            f"got {type(vecnormalize).__name__}.")
        vecnormalize.training = False  # an evaluation object: its running statistics must not move
    elif needs_normalization(model):
        raise ValueError("the model was trained on VecNormalize-d observations: pass vecnormalize= the "
                         "VecNormalize saved with it (VecNormalize.load(path, venv)), or "
                         "model.get_vec_normalize_env() for a model still in memory.")
    kind = action_mode.apply(policy)
    return _Actor(policy, action_mode, vecnormalize), kind


def fits_policy(shape: tuple[int, ...], policy: BasePolicy) -> bool:
    """Whether the policy takes states of ``shape``; SB3 transposes channel-last images itself."""
    space = policy.observation_space
    if shape == space.shape:
        return True
    return is_image_space(space) and len(shape) == 3 and shape == (space.shape[1], space.shape[2], space.shape[0])


def _check_obs_space(venv: VecEnv, policy: BasePolicy) -> None:
    if not fits_policy(venv.observation_space.shape, policy):
        raise ValueError(f"the env gives observations of shape {venv.observation_space.shape} but the policy "
                         f"takes {policy.observation_space.shape}: use the env the model was trained on.")


# ---------------------------------------------------------------------- the collection loop


@dataclass
class _Episode:
    """Kept states of one episode; ``unstable`` says why it blew up, if it did."""

    states: list[np.ndarray] = field(default_factory=list)
    policy_obs: list[np.ndarray] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    indicator: list[int] = field(default_factory=list)
    unstable: str | None = None
    next_obs: np.ndarray | None = None  # the next episode's first obs after the env ended and auto-reset


@dataclass
class _Run:
    """One configuration: an env and what to record about it."""

    venv: VecEnv
    source: str
    config_json: str | None
    describe: str
    check: Callable[[VecEnv, np.ndarray, bool], str | None] | None = None
    indicator: Callable[[], int] | None = None  # the OOD source's indicator now (Atari), read per kept state


def _mujoco_instability(venv: VecEnv, obs: np.ndarray, reset_happened: bool) -> str | None:
    """NaN/inf or exploding observation, or MuJoCo's own instability flags (cleared by a reset)."""
    if is_unstable(obs):
        return "non-finite or exploding observation"
    if not reset_happened:
        data = venv.envs[0].unwrapped.data
        for warning in _MUJOCO_INSTABILITY:
            if data.warning[warning].number > 0:
                return f"MuJoCo {warning.name} (simulation unstable)"
    return None


def _run_episode(run: _Run, obs: np.ndarray, actor: _Actor, max_episode_steps: int, skip_first: int,
                 budget: int) -> _Episode:
    """Act from ``obs`` until the episode ends, the step limit, or ``budget`` kept states."""
    episode = _Episode()
    if run.check is not None and (reason := run.check(run.venv, obs[0], True)):
        episode.unstable = f"{reason} at reset"
        return episode
    policy_obs = actor.policy_obs(obs)
    for t in range(max_episode_steps):
        if t >= skip_first:
            episode.states.append(obs[0].copy())
            if actor.vecnormalize is not None:  # else policy_obs is obs: no second copy of every frame
                episode.policy_obs.append(policy_obs[0].copy())
            episode.steps.append(t)
            if run.indicator is not None:
                episode.indicator.append(run.indicator())
            if len(episode.steps) >= budget:
                return episode
        obs, _, dones, infos = run.venv.step(actor.act(policy_obs))
        last = infos[0]["terminal_observation"] if dones[0] else obs[0]
        if run.check is not None and (reason := run.check(run.venv, last, bool(dones[0]))):
            episode.unstable = f"{reason} at step {t + 1}"
            return episode
        if dones[0]:
            episode.next_obs = obs
            return episode
        policy_obs = actor.policy_obs(obs)
    return episode


@dataclass
class _Buffer:
    """Committed states of the whole collection, in order."""

    states: list[np.ndarray] = field(default_factory=list)
    policy_obs: list[np.ndarray] = field(default_factory=list)
    source: list[str] = field(default_factory=list)
    config_index: list[int] = field(default_factory=list)
    episode: list[int] = field(default_factory=list)
    step: list[int] = field(default_factory=list)
    indicator: list[int] = field(default_factory=list)
    configs: list[str] = field(default_factory=list)
    n_episodes: int = 0

    def add(self, run: _Run, episodes: list[_Episode]) -> None:
        """Append a configuration's episodes; ones that ended before ``skip_first`` leave no trace."""
        episodes = [ep for ep in episodes if ep.steps]
        if not episodes:
            return
        index = NO_CONFIG
        if run.config_json is not None:
            index = len(self.configs)
            self.configs.append(run.config_json)
        for ep in episodes:
            n = len(ep.steps)
            self.states += ep.states
            self.policy_obs += ep.policy_obs
            self.step += ep.steps
            self.indicator += ep.indicator
            self.source += [run.source] * n
            self.config_index += [index] * n
            self.episode += [self.n_episodes] * n
            self.n_episodes += 1

    def dataset(self, label: int, metadata: dict[str, Any], with_policy_obs: bool) -> StateDataset:
        return StateDataset(
            states=np.stack(self.states), labels=np.full(len(self.states), label), source=self.source,
            config_index=self.config_index, episode=self.episode, step=self.step, configs=self.configs,
            metadata=metadata, policy_obs=np.stack(self.policy_obs) if with_policy_obs else None,
            source_indicator=np.array(self.indicator) if self.indicator else None,
        )


def _collect(actor: _Actor, next_run: Callable[[], _Run], n_states: int, steps_per_config: int | None,
             max_episode_steps: int, skip_first: int, seed: int) -> tuple[_Buffer, int]:
    """The protocol of the module docstring. Returns the states and the number of rejected configurations."""
    buffer, rejected, unstable_in_a_row, empty_in_a_row = _Buffer(), 0, 0, 0
    with th.random.fork_rng(devices=[]):
        th.manual_seed(seed)
        while len(buffer.states) < n_states:
            run = next_run()
            target = min(steps_per_config or math.inf, n_states - len(buffer.states))
            episodes: list[_Episode] = []
            kept, unstable, empty_here = 0, None, 0
            try:
                _check_obs_space(run.venv, actor.policy)
                obs = run.venv.reset()
                while kept < target:
                    episode = _run_episode(run, obs, actor, max_episode_steps, skip_first, target - kept)
                    if episode.unstable is not None:
                        unstable = episode.unstable
                        break
                    episodes.append(episode)
                    kept += len(episode.steps)
                    empty_in_a_row = 0 if episode.steps else empty_in_a_row + 1
                    empty_here = 0 if episode.steps else empty_here + 1
                    if empty_in_a_row >= MAX_EMPTY_IN_A_ROW:
                        raise RuntimeError(f"{empty_in_a_row} episodes in a row ended before skip_first="
                                           f"{skip_first} steps ({run.describe}): lower skip_first or check the agent.")
                    if empty_here >= MAX_EMPTY_PER_CONFIG:
                        unstable = f"{empty_here} episodes in a row ended before skip_first={skip_first} steps"
                        break
                    if steps_per_config is None:
                        break  # appendix protocol: a new configuration at every restart
                    obs = episode.next_obs if episode.next_obs is not None else run.venv.reset()
            finally:
                run.venv.close()
            if unstable is None:
                buffer.add(run, episodes)
                unstable_in_a_row = 0
                continue
            rejected += 1
            unstable_in_a_row += 1
            config = f" ({run.config_json})" if run.config_json is not None else ""
            warnings.warn(f"Discarded {run.describe}{config}: {unstable} under the agent's actions; "
                          "its states are dropped and a new configuration is drawn.",
                          UnstablePerturbationWarning, stacklevel=3)
            if unstable_in_a_row >= MAX_UNSTABLE_IN_A_ROW:
                raise RuntimeError(f"{unstable_in_a_row} configurations in a row went unstable (last: {unstable}); "
                                   "narrow the perturbation ranges.")
    return buffer, rejected


def _protocol(n_states: int | None, configs: int | None, steps_per_config: int | None,
              default: dict[str, int] = MAIN_TEXT_PROTOCOL) -> tuple[int, int | None, str]:
    """(n_states, steps per cluster or None, protocol name) from the arguments.

    Nothing given: the main text's protocol (``default``); ``n_states`` alone: the appendix
    protocol; both cluster arguments (names as in ``default``): the main text's with them.
    """
    names = list(default)
    if configs is None and steps_per_config is None and n_states is None:
        configs, steps_per_config = default.values()
    if (configs is None) != (steps_per_config is None):
        raise ValueError(f"{names[0]}={configs}, {names[1]}={steps_per_config}: give both (main-text protocol: "
                         f"{default}) or neither (appendix protocol: n_states, a new env per episode).")
    if configs is None:
        return n_states, None, "appendix"
    for name, value in zip(names, (configs, steps_per_config)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
            raise ValueError(f"{name}={value!r}: need a positive int.")
    if n_states is not None and n_states != configs * steps_per_config:
        raise ValueError(f"n_states={n_states} but {names[0]} x {names[1]} = {configs * steps_per_config}: "
                         f"leave n_states=None with {names[0]} and {names[1]}.")
    return configs * steps_per_config, int(steps_per_config), "main"


def _model_info(model: BaseAlgorithm | BasePolicy) -> dict[str, Any] | None:
    """Which trained agent acted (from make_agent's config), so ID and OOD files can be matched."""
    config = getattr(model, "paper_lib_config", None) or {}
    info = {k: config[k] for k in ("algo", "method", "env_id", "seed", "n_members") if k in config}
    return info or None


def _metadata(kind: str, env_id: str, model: BaseAlgorithm | BasePolicy, action_mode: ActionMode, policy_kind: str,
              seed: int, vecnormalize: Any, protocol: dict[str, Any], buffer: _Buffer, rejected: int,
              **extra: Any) -> dict[str, Any]:
    return dict(kind=kind, env_id=env_id, model=_model_info(model), action_mode=action_mode.to_dict(),
                policy=policy_kind, seed=int(seed),
                vecnormalize=vecnormalize is not None, protocol=protocol, n_episodes=buffer.n_episodes,
                n_configs=len(buffer.configs), n_rejected_configs=rejected, **extra)


# ------------------------------------------------------------------------------ env makers


def _indicator_reader(env: gym.Env, game: str, source: str) -> Callable[[], int]:
    """Reads ``source``'s indicator from ``env``'s emulator, for ``_Run.indicator``."""
    return lambda: read_indicator(env, game, source)


def _indicator_metadata(game: str, source: str) -> dict[str, str]:
    """What a dataset's ``source_indicator`` holds: the source and the quantity read."""
    return {"game": game, "source": source, "read": indicator_name(game, source)}


def _atari_venv(env: gym.Env) -> VecEnv:
    """One env stacked like the agent's training env: (1, 84, 84, 4) uint8."""
    return VecFrameStack(DummyVecEnv([lambda: env]), N_STACK)


def _seeded_venv(env: gym.Env, seed: int) -> VecEnv:
    venv = DummyVecEnv([lambda: env])
    venv.seed(seed)  # used by the next reset
    return venv


def _check_env_id(env_id: str) -> None:
    if is_atari(env_id):
        game_of(env_id)
        return
    try:
        gym.spec(env_id)
    except gym.error.Error as err:
        raise ValueError(f"unknown env id {env_id!r} ({err}); the paper's envs are {list(SUPPORTED_ENVS)} "
                         f"and {[atari_env_id(g) for g in ATARI_GAMES]}.") from err


# ----------------------------------------------------------------------------- collectors


def collect_id_states(model: BaseAlgorithm | BasePolicy, env_id: str, n_states: int | None = None, *,
                      action_mode: ActionMode, seed: int, max_episode_steps: int = 500, skip_first: int = 10,
                      episodes: int | None = None, steps_per_episode: int | None = None,
                      vecnormalize: VecNormalize | None = None, indicator_source: str | None = None) -> StateDataset:
    """ID states: the agent acting in the unmodified env, one fresh env seed per run.

    Default, the main-text protocol's counterpart (``ID_MAIN_PROTOCOL``): ``episodes`` runs of
    exactly ``steps_per_episode`` kept states each (restarting within the run if an episode
    ends early); ``n_states`` alone: appendix G's, a fresh env seed per episode until
    ``n_states``. Same ``max_episode_steps`` / ``skip_first`` as the OOD collection, so both
    samples cover the same part of an episode. Atari envs are wrapped like the OOD ones, and
    every kept state records the indicator of ``indicator_source`` (the game's default OOD
    source if None; give the source the OOD states will come from), so the coverage check
    (``paper_lib.ood.coverage``) uses exactly these rollouts.
    """
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a gymnasium id string, got {type(env_id).__name__}.")
    _check_env_id(env_id)
    game = game_of(env_id) if is_atari(env_id) else None
    if game is None and indicator_source is not None:
        raise ValueError(f"indicator_source={indicator_source!r} applies to Atari games only; drop it for {env_id}.")
    if game is not None:
        indicator_source = DEFAULT_SOURCE[game] if indicator_source is None else indicator_source
        source_values(game, indicator_source)  # a bad source fails here, before any rollout
    n_states, steps_per_run, protocol_name = _protocol(n_states, episodes, steps_per_episode, ID_MAIN_PROTOCOL)
    actor, policy_kind = _prepare(model, env_id, n_states, action_mode, seed, max_episode_steps, skip_first,
                                  vecnormalize)
    rng = np.random.default_rng(seed)
    if game is not None:
        register_atari()

    def next_run() -> _Run:
        env_seed = int(rng.integers(2**31 - 1))
        if game is not None:
            env = make_atari_env_single(game, seed=env_seed)
            return _Run(_atari_venv(env), ID_SOURCE, None, f"{env_id} (seed {env_seed})",
                        indicator=_indicator_reader(env, game, indicator_source))
        venv = _seeded_venv(make_single_env(env_id), env_seed)
        check = _mujoco_instability if env_id in SUPPORTED_ENVS else None
        return _Run(venv, ID_SOURCE, None, f"{env_id} (seed {env_seed})", check)

    buffer, rejected = _collect(actor, next_run, n_states, steps_per_run, max_episode_steps, skip_first, seed)
    protocol = dict(name="id" if protocol_name == "appendix" else "id_main", n_states=int(n_states),
                    max_episode_steps=max_episode_steps, skip_first=skip_first)
    if protocol_name == "main":
        protocol.update(episodes=episodes or ID_MAIN_PROTOCOL["episodes"], steps_per_episode=steps_per_run)
    extra = {} if game is None else {"source_indicator": _indicator_metadata(game, indicator_source)}
    metadata = _metadata("id", env_id, model, action_mode, policy_kind, seed, vecnormalize, protocol, buffer, rejected,
                         **extra)
    return buffer.dataset(ID_LABEL, metadata, with_policy_obs=vecnormalize is not None)


def collect_mujoco_ood_states(model: BaseAlgorithm | BasePolicy, env_id: str, n_states: int | None = None, *,
                              action_mode: ActionMode, seed: int, max_episode_steps: int = 500, skip_first: int = 10,
                              configs: int | None = None, steps_per_config: int | None = None,
                              ranges: PerturbationRanges = PerturbationRanges(),
                              vecnormalize: VecNormalize | None = None, probe_steps: int = 200,
                              max_tries: int = 20) -> StateDataset:
    """OOD states: the agent acting in sampled, stable physics perturbations (section 5, appendix G).

    Default, the main text's protocol (``MAIN_TEXT_PROTOCOL``): 50 configurations x 100 kept
    states (or ``configs`` x ``steps_per_config``); ``skip_first=0`` reads it literally (no
    skip). ``n_states`` alone: appendix G's protocol, a new configuration per episode.
    ``probe_steps`` / ``max_tries`` go to ``sample_stable_config``, which rejects configs
    that blow up under random actions before the agent ever acts in them.
    """
    if env_id not in SUPPORTED_ENVS:
        raise ValueError(f"unknown MuJoCo env {env_id!r}: use one of {list(SUPPORTED_ENVS)}.")
    if not isinstance(ranges, PerturbationRanges):
        raise TypeError(f"ranges must be a PerturbationRanges, got {type(ranges).__name__}.")
    n_states, steps_per_config, protocol_name = _protocol(n_states, configs, steps_per_config)
    configs = None if steps_per_config is None else n_states // steps_per_config
    actor, policy_kind = _prepare(model, env_id, n_states, action_mode, seed, max_episode_steps, skip_first,
                                  vecnormalize)
    rng = np.random.default_rng(seed)

    def next_run() -> _Run:
        config = sample_stable_config(env_id, rng, ranges, probe_steps=probe_steps, max_tries=max_tries)
        venv = _seeded_venv(make_perturbed_env(config), config.seed)
        return _Run(venv, "+".join(config.kinds), config.to_json(), config.describe(), _mujoco_instability)

    buffer, rejected = _collect(actor, next_run, n_states, steps_per_config, max_episode_steps, skip_first, seed)
    protocol = dict(name=protocol_name, n_states=int(n_states), max_episode_steps=max_episode_steps,
                    skip_first=skip_first, configs=configs, steps_per_config=steps_per_config,
                    probe_steps=probe_steps)
    metadata = _metadata("mujoco_ood", env_id, model, action_mode, policy_kind, seed, vecnormalize, protocol, buffer,
                         rejected, ranges=dataclasses.asdict(ranges))
    return buffer.dataset(OOD_LABEL, metadata, with_policy_obs=vecnormalize is not None)


def collect_atari_ood_states(model: BaseAlgorithm | BasePolicy, env_id: str, n_states: int | None = None, *,
                             action_mode: ActionMode, seed: int, max_episode_steps: int = 500, skip_first: int = 10,
                             configs: int | None = None, steps_per_config: int | None = None,
                             source: str | None = None) -> StateDataset:
    """OOD Atari states (uint8, 84x84x4): the agent playing sampled ``AtariOODConfig`` games.

    The same protocols as MuJoCo (default: the main text's); ``source`` picks the kind of
    edit (the game's default if None, see ``paper_lib.ood.atari.OOD_SOURCE_NOTES``). An
    "episode" is what the agent's wrappers call one: it ends at a lost life. Every kept state
    records the source's indicator, which shows the edit in force (or, for a game counter
    such as Berzerk's rooms, moved on by play).
    """
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be an Atari id like 'SeaquestNoFrameskip-v4', got {type(env_id).__name__}.")
    game = game_of(env_id)
    n_states, steps_per_config, protocol_name = _protocol(n_states, configs, steps_per_config)
    configs = None if steps_per_config is None else n_states // steps_per_config
    actor, policy_kind = _prepare(model, env_id, n_states, action_mode, seed, max_episode_steps, skip_first, None)
    rng = np.random.default_rng(seed)
    sample_atari_config(game, np.random.default_rng(0), source)  # a bad source fails here, before any rollout

    def next_run() -> _Run:
        config = sample_atari_config(game, rng, source)
        env = make_ood_atari_env(config)
        return _Run(_atari_venv(env), config.source, config.to_json(), f"{game} {config.source}={config.value}",
                    indicator=_indicator_reader(env, game, config.source))

    buffer, rejected = _collect(actor, next_run, n_states, steps_per_config, max_episode_steps, skip_first, seed)
    protocol = dict(name=protocol_name, n_states=int(n_states), max_episode_steps=max_episode_steps,
                    skip_first=skip_first, configs=configs, steps_per_config=steps_per_config)
    metadata = _metadata("atari_ood", env_id, model, action_mode, policy_kind, seed, None, protocol, buffer, rejected,
                         source=source, source_indicator=_indicator_metadata(game, source or DEFAULT_SOURCE[game]))
    return buffer.dataset(OOD_LABEL, metadata, with_policy_obs=False)


# ------------------------------------------------------------------- OOD derived from ID states


def _check_id_dataset(dataset: StateDataset) -> None:
    if not isinstance(dataset, StateDataset):
        raise TypeError(f"expected a StateDataset of ID states, got {type(dataset).__name__}.")
    if len(dataset) == 0 or (dataset.labels != ID_LABEL).any():
        raise ValueError("pass a non-empty dataset of ID states only (dataset.id_only()).")


def _derived(dataset: StateDataset, states: np.ndarray, source: str, policy_obs: np.ndarray | None,
             **metadata: Any) -> StateDataset:
    """OOD copies of ``dataset``'s rows: provenance (episode, step, config) kept from the ID states."""
    return StateDataset(states=states, labels=np.full(len(states), OOD_LABEL), source=[source] * len(states),
                        config_index=dataset.config_index, episode=dataset.episode, step=dataset.step,
                        configs=dataset.configs, metadata={**dataset.metadata, **metadata}, policy_obs=policy_obs)


def pixel_ood_states(id_dataset: StateDataset, kinds: Sequence[str] | str,
                     rng: np.random.Generator) -> StateDataset:
    """Appendix H: every ID image state perturbed by each of ``kinds`` (source "pixels:<kind>")."""
    _check_id_dataset(id_dataset)
    kinds = [kinds] if isinstance(kinds, str) else list(kinds)
    bad = [k for k in kinds if k not in PIXEL_PERTURBATIONS]
    if not kinds or bad:
        raise ValueError(f"kinds={kinds}: give a non-empty list from {list(PIXEL_PERTURBATIONS)}.")
    out: StateDataset | None = None
    for kind in kinds:
        part = _derived(id_dataset, perturb_pixels(id_dataset.states, kind, rng), f"pixels:{kind}", None,
                        kind="pixels", derived_from="id", pixel_kinds=kinds)
        out = part if out is None else _concat_same(out, part)
    assert out is not None
    return out


def _concat_same(a: StateDataset, b: StateDataset) -> StateDataset:
    """Stack two derived datasets that share configs and metadata."""
    return StateDataset(states=np.concatenate([a.states, b.states]), labels=np.concatenate([a.labels, b.labels]),
                        source=np.concatenate([a.source, b.source]),
                        config_index=np.concatenate([a.config_index, b.config_index]),
                        episode=np.concatenate([a.episode, b.episode]), step=np.concatenate([a.step, b.step]),
                        configs=a.configs, metadata=a.metadata)


def noise_ood_states(id_dataset: StateDataset, rng: np.random.Generator, magnitude: float = 2.0,
                     vecnormalize: VecNormalize | None = None) -> StateDataset:
    """Section 5's cheap OOD states: ID states + uniform noise of +-magnitude x their element-wise std.

    Noise is added to the raw states. With a VecNormalize (per-element affine), that is the
    same noise relative to the std of what the policy sees; ``vecnormalize`` then gives the
    noisy states' ``policy_obs`` and is required if the ID dataset has them.
    """
    _check_id_dataset(id_dataset)
    if id_dataset.policy_obs is not None and not isinstance(vecnormalize, VecNormalize):
        raise ValueError("the ID dataset was collected with VecNormalize: pass the same vecnormalize so the "
                         "noisy states get the policy's normalized observations too.")
    states = noise_ood(id_dataset.states, rng, magnitude)
    policy_obs = None
    if id_dataset.policy_obs is not None:
        vecnormalize.training = False
        policy_obs = vecnormalize.normalize_obs(states)
    return _derived(id_dataset, states, "noise", policy_obs, kind="noise", derived_from="id",
                    noise_magnitude=float(magnitude))
