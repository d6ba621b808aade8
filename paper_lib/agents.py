"""make_agent: algorithm + method + env + the paper's hyperparameters -> a ready SB3 model."""

from __future__ import annotations

import copy
from importlib import resources
from typing import Any

import yaml
from sb3_contrib import TRPO
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from paper_lib.envs import is_atari, make_env
from paper_lib.methods.buffer import MemberOrderedRolloutBuffer
from paper_lib.methods.groups import MemberGroupVecEnv, check_member_layout
from paper_lib.methods.layers import validate_masksembles
from paper_lib.methods.networks import METHODS, MemberSpec
from paper_lib.methods.policy import INFERENCE_MODES, MemberActorCriticPolicy

ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "a2c": A2C, "trpo": TRPO}
ASSIGNMENTS = ("shared", "own")
#: Which of the paper's PPO settings each algorithm takes.
ALGO_KEYS = {
    "ppo": None,  # all
    "a2c": ("learning_rate", "n_steps", "gamma", "gae_lambda", "ent_coef", "vf_coef", "max_grad_norm"),
    "trpo": ("learning_rate", "n_steps", "batch_size", "gamma", "gae_lambda"),
}


#: Policy settings a hyperparameter table may give (SB3 `policy_kwargs`, MLP envs only).
ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU}
POLICY_KEYS = ("activation_fn", "log_std_init", "ortho_init")
MEMBER_KEYS = ("n_members", "dropout_p", "masksembles_scale")


def policy_settings(hp: dict[str, Any], env_id: str) -> dict[str, Any]:
    """The table's `policy` entry as SB3 policy_kwargs (activation names -> classes).

    The paper's MuJoCo numbers are rl-baselines3-zoo's tuned entries, which come with these
    settings (log_std_init=-2, ortho_init=False, ReLU for HalfCheetah and Swimmer); member
    policies honour them exactly as `MlpPolicy` does.
    """
    raw = dict(hp.get("policy") or {})
    unknown = sorted(set(raw) - set(POLICY_KEYS))
    if unknown:
        raise ValueError(f"hyperparameters for {env_id}: unknown policy setting(s) {unknown}; known: {list(POLICY_KEYS)}")
    if "activation_fn" in raw:
        if raw["activation_fn"] not in ACTIVATIONS:
            raise ValueError(f"hyperparameters for {env_id}: activation_fn={raw['activation_fn']!r}; "
                             f"use one of {sorted(ACTIVATIONS)}")
        raw["activation_fn"] = ACTIVATIONS[raw["activation_fn"]]
    return raw


def member_settings(hp: dict[str, Any], env_id: str, **explicit: Any) -> dict[str, Any]:
    """k, dropout p and Masksembles scale: an explicit argument wins over the table's `members`."""
    table = dict(hp.get("members") or {})
    unknown = sorted(set(table) - set(MEMBER_KEYS))
    if unknown:
        raise ValueError(f"hyperparameters for {env_id}: unknown member setting(s) {unknown}; known: {list(MEMBER_KEYS)}")
    resolved = {key: explicit[key] if explicit.get(key) is not None else table.get(key) for key in MEMBER_KEYS}
    missing = [key for key, value in resolved.items() if value is None]
    if missing:
        raise ValueError(f"hyperparameters for {env_id} lack members.{missing}; add e.g. "
                         "`members: {n_members: 4, dropout_p: 0.1, masksembles_scale: 2.0}` or pass them to make_agent")
    return resolved


def paper_hyperparameters(env_id: str) -> dict[str, Any]:
    """The paper's settings for `env_id` (a fresh copy, safe to edit)."""
    table = yaml.safe_load(resources.files("paper_lib.data").joinpath("paper_hyperparameters.yaml").read_text())
    known = sorted(k for k in table if not k.startswith("_"))
    if env_id not in known:
        raise ValueError(f"unknown environment {env_id!r}; paper_lib has hyperparameters for {known}")
    return copy.deepcopy(table[env_id])


def make_agent(
    algo: str,
    method: str,
    env_id: str,
    seed: int = 0,
    *,
    n_members: int | None = None,
    assignment: str = "shared",
    inference: str = "vote",
    dropout_p: float | None = None,
    masksembles_scale: float | None = None,
    n_envs: int | None = None,
    overrides: dict[str, Any] | None = None,
    hyperparameters: dict[str, Any] | None = None,
    env: VecEnv | None = None,
    device: str = "cpu",
    verbose: int = 0,
    tensorboard_log: str | None = None,
) -> BaseAlgorithm:
    """Build an SB3 model with the paper's hyperparameters for `env_id` and the given method.

    `hyperparameters` replaces the packaged table entry for `env_id` (the pipeline passes
    params.yaml's). `overrides` replaces entries of the algorithm settings (e.g. {"n_steps": 64}). Every
    input is checked before an env or network is built. The resolved settings are kept on the
    model as `model.paper_lib_config` and saved with it.
    """
    if algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algo!r}; use one of {sorted(ALGORITHMS)}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; use one of {METHODS}")
    if assignment not in ASSIGNMENTS:
        raise ValueError(f"unknown assignment {assignment!r}; use one of {ASSIGNMENTS}")
    if inference not in INFERENCE_MODES:
        raise ValueError(f"unknown inference mode {inference!r}; use one of {INFERENCE_MODES}")
    hp = paper_hyperparameters(env_id) if hyperparameters is None else copy.deepcopy(hyperparameters)
    members = member_settings(hp, env_id, n_members=n_members, dropout_p=dropout_p, masksembles_scale=masksembles_scale)
    n_members, dropout_p, masksembles_scale = members["n_members"], members["dropout_p"], members["masksembles_scale"]
    mlp_settings = {} if is_atari(env_id) else policy_settings(hp, env_id)
    algo_kwargs = {**hp["algo"], **(overrides or {})}
    unknown = set(overrides or {}) - set(hp["algo"])
    if unknown:
        raise ValueError(f"unknown override(s) {sorted(unknown)}; known settings are {sorted(hp['algo'])}")
    if ALGO_KEYS[algo] is not None:
        algo_kwargs = {k: v for k, v in algo_kwargs.items() if k in ALGO_KEYS[algo]}
    n_envs = n_envs or hp["n_envs"]
    hidden = hp.get("hidden_sizes_masksembles", hp.get("hidden_sizes")) if method == "masksembles" else hp.get("hidden_sizes")

    if method != "baseline":
        MemberSpec(method, n_members, dropout_p, masksembles_scale, seed)  # validates k and p
        check_member_layout(n_envs, n_members, algo_kwargs.get("batch_size"), algo_kwargs["n_steps"])
        if method == "masksembles":
            widths = [32, 512] if is_atari(env_id) else hidden[:2]
            for width in widths:
                validate_masksembles(width, n_members, masksembles_scale)

    config = dict(algo=algo, method=method, env_id=env_id, seed=seed, n_envs=n_envs, n_members=n_members,
                  assignment=assignment, inference=inference, dropout_p=dropout_p,
                  masksembles_scale=masksembles_scale, hidden_sizes=hidden, normalize_obs=hp["normalize_obs"],
                  policy=dict(hp.get("policy") or {}) if mlp_settings else {},
                  algo_kwargs=dict(algo_kwargs), linear_lr_decay=bool(hp.get("linear_lr_decay", False)),
                  total_timesteps=hp.get("total_timesteps"))

    if env is None:
        env = make_env(env_id, n_envs, seed, normalize_obs=hp["normalize_obs"])
    elif env.num_envs != n_envs:
        raise ValueError(f"the given env has {env.num_envs} envs but n_envs={n_envs}")
    if config["linear_lr_decay"]:
        algo_kwargs["learning_rate"] = LinearSchedule(algo_kwargs["learning_rate"], 0.0, 1.0)

    if method == "baseline":
        policy: Any = "CnnPolicy" if is_atari(env_id) else "MlpPolicy"
        policy_kwargs: dict[str, Any] = {} if is_atari(env_id) else {"net_arch": {"pi": hidden, "vf": hidden},
                                                                      **mlp_settings}
    else:
        env = MemberGroupVecEnv(env, n_members)
        policy = MemberActorCriticPolicy
        policy_kwargs = dict(method=method, n_members=n_members, dropout_p=dropout_p,
                             masksembles_scale=masksembles_scale, member_seed=seed, inference=inference)
        if not is_atari(env_id):
            policy_kwargs.update(hidden_sizes=tuple(hidden), **mlp_settings)
        if assignment == "own":
            algo_kwargs["rollout_buffer_class"] = MemberOrderedRolloutBuffer
            algo_kwargs["rollout_buffer_kwargs"] = {"n_members": n_members}

    model = ALGORITHMS[algo](policy, env, seed=seed, device=device, verbose=verbose, policy_kwargs=policy_kwargs,
                             tensorboard_log=tensorboard_log, **algo_kwargs)
    model.paper_lib_config = config
    return model
