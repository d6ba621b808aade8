"""make_agent: algorithm + method + env + the paper's hyperparameters -> a ready SB3 model."""

from __future__ import annotations

import copy
import math
from importlib import resources
from typing import Any

import numpy as np
import torch as th
import yaml
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from paper_lib.agents.envs import check_given_env, is_atari, make_env
from paper_lib.common.checks import check_keys
from paper_lib.methods.buffer import MemberOrderedRolloutBuffer
from paper_lib.methods.groups import MemberGroupVecEnv, check_groups_match, check_member_layout
from paper_lib.methods.layers import validate_masksembles
from paper_lib.methods.networks import METHODS, MemberSpec
from paper_lib.methods.policy import INFERENCE_MODES, MemberActorCriticPolicy
from paper_lib.methods.trpo import MaskConsistentTRPO

#: sb3-contrib's TRPO, with one set of random masks per policy step for MC Dropout / DropConnect (see paper_lib.methods.trpo).
ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "a2c": A2C, "trpo": MaskConsistentTRPO}
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


#: The algorithm settings a hyperparameter table gives (SB3 PPO keyword arguments), each with its check.
ALGO_SETTINGS = ("batch_size", "learning_rate", "n_epochs", "n_steps", "gae_lambda", "gamma", "ent_coef", "vf_coef",
                 "max_grad_norm", "clip_range")
#: Top-level keys of a hyperparameter entry; the first four are required.
HP_REQUIRED = ("n_envs", "normalize_obs", "total_timesteps", "algo")
HP_OPTIONAL = ("policy", "members", "hidden_sizes", "hidden_sizes_masksembles", "linear_lr_decay", "normalize_reward")
#: Run-config keys added after runs were committed, with the value older config.json files mean.
CONFIG_DEFAULTS: dict[str, Any] = {"normalize_reward": False}


def config_value(config: dict[str, Any], key: str) -> Any:
    """A run config's setting, reading a key that older runs did not record as its default."""
    return config.get(key, CONFIG_DEFAULTS.get(key))


def check_integer(value: Any, name: str, where: str, minimum: int | None = None) -> int:
    """`value` as a plain int, or one ValueError naming `where`, the setting and what to write.

    Booleans and floats (even 2.0) are refused: YAML and Python both let them pass for numbers.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        hint = f" (write {int(value)})" if isinstance(value, float) and value.is_integer() else ""
        raise ValueError(f"{where}: {name} must be an integer, got {value!r}{hint}")
    if minimum is not None and value < minimum:
        raise ValueError(f"{where}: {name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_number(value: Any, name: str, where: str, low: float | None = None, high: float | None = None,
                 low_open: bool = False, high_open: bool = False) -> float:
    """A finite real number in [low, high] (open ends where asked), or one ValueError saying what to write.

    YAML 1.1 reads `3e-4` (no dot) as the string '3e-4': that case gets its own fix.
    """
    if isinstance(value, str):
        try:
            parsed = float(value)
        except ValueError:
            parsed = None
        if parsed is not None and math.isfinite(parsed):
            mantissa, e, exponent = value.strip().lower().partition("e")
            fixed = (mantissa if "." in mantissa else f"{mantissa}.0") + (f"e{exponent}" if e else "")
            raise ValueError(f"{where}: {name}={value!r} is text, not a number (YAML reads a number without a dot "
                             f"before its exponent, or in quotes, as text); write {fixed}")
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise ValueError(f"{where}: {name} must be a finite number, got {value!r}")
    too_low = low is not None and (value <= low if low_open else value < low)
    too_high = high is not None and (value >= high if high_open else value > high)
    if too_low or too_high:
        interval = (("(" if low_open or low is None else "[") + ("-inf" if low is None else f"{low:g}") + ", "
                    + ("inf" if high is None else f"{high:g}") + (")" if high_open or high is None else "]"))
        raise ValueError(f"{where}: {name}={value!r} is outside {interval}")
    return float(value)


def check_seed(seed: Any, where: str = "make_agent") -> int:
    """Seeds are integers >= 0 (numpy refuses negative ones; '0' is a string, not a seed)."""
    return check_integer(seed, "seed", where, minimum=0)


def device_available(device: th.device) -> bool:
    """Whether torch can use `device` here; SB3 itself would quietly train a missing CUDA device on the CPU."""
    if device.type == "cpu":
        return True
    if device.type == "cuda":
        return th.cuda.is_available() and (device.index is None or device.index < th.cuda.device_count())
    backend = getattr(th.backends, device.type, None) or getattr(th, device.type, None)
    is_available = getattr(backend, "is_available", None)
    return bool(is_available()) if callable(is_available) else True  # no probe: torch itself will say


def check_device(device: Any, where: str = "make_agent") -> Any:
    """An explicit device must exist ("auto" picks the GPU when there is one, else the CPU); returned unchanged."""
    if isinstance(device, str) and device == "auto":
        return device
    try:
        parsed = th.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"{where}: device must be a torch device such as 'cpu', 'cuda' or 'auto', got {device!r}; "
                         "use device='auto' to take the GPU when there is one") from None
    if not device_available(parsed):
        gpus = th.cuda.device_count() if th.cuda.is_available() else 0
        raise ValueError(f"{where}: device {str(parsed)!r} is not available on this machine ({gpus} CUDA device(s)), "
                         f"got device={device!r}; use device='cpu', or 'auto' to take the GPU when there is one")
    return device


def _check_mapping(value: Any, name: str, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ValueError(f"{where}: {name} must be a mapping (key: value), got {value!r}")
    return value


def check_algo_settings(settings: Any, where: str, name: str = "algo", required: bool = True) -> None:
    """Known keys, integers where SB3 needs counts, numbers in their valid ranges."""
    settings = _check_mapping(settings, name, where)
    unknown = sorted(set(settings) - set(ALGO_SETTINGS))
    if unknown:
        raise ValueError(f"{where}: unknown {name} setting(s) {unknown}; known: {sorted(ALGO_SETTINGS)}")
    missing = [key for key in ALGO_SETTINGS if key not in settings] if required else []
    if missing:
        raise ValueError(f"{where}: {name} lacks {missing}; every entry gives all of {sorted(ALGO_SETTINGS)}")
    checks = {
        "batch_size": lambda v, n: check_integer(v, n, where, minimum=2),  # SB3 needs > 1
        "n_epochs": lambda v, n: check_integer(v, n, where, minimum=1),
        "n_steps": lambda v, n: check_integer(v, n, where, minimum=1),
        "learning_rate": lambda v, n: check_number(v, n, where, low=0.0, low_open=True),
        "gae_lambda": lambda v, n: check_number(v, n, where, low=0.0, high=1.0),
        "gamma": lambda v, n: check_number(v, n, where, low=0.0, high=1.0),
        "ent_coef": lambda v, n: check_number(v, n, where, low=0.0),
        "vf_coef": lambda v, n: check_number(v, n, where, low=0.0),
        "max_grad_norm": lambda v, n: check_number(v, n, where, low=0.0, low_open=True),
        "clip_range": lambda v, n: check_number(v, n, where, low=0.0, low_open=True),
    }
    for key, value in settings.items():
        if callable(value) and key in ("learning_rate", "clip_range"):  # an SB3 schedule, given in Python
            continue
        checks[key](value, f"{name}.{key}")


def check_widths(widths: Any, name: str, where: str) -> None:
    if not isinstance(widths, (list, tuple)) or not widths:
        raise ValueError(f"{where}: {name} must be a non-empty list of layer widths, e.g. [64, 64]; got {widths!r}")
    for i, width in enumerate(widths):
        check_integer(width, f"{name}[{i}]", where, minimum=1)


def validate_hyperparameters(hp: Any, env_id: str, where: str | None = None) -> None:
    """Check one env's hyperparameter entry (keys, types, ranges) before anything is built from it."""
    where = where or f"hyperparameters for {env_id}"
    hp = _check_mapping(hp, "the entry", where)
    required = [*HP_REQUIRED, *([] if is_atari(env_id) else ["hidden_sizes"])]
    check_keys(hp, where, sorted(HP_REQUIRED + HP_OPTIONAL), required,
               fix="see paper_lib/data/paper_hyperparameters.yaml for a full entry")
    check_integer(hp["n_envs"], "n_envs", where, minimum=1)
    check_integer(hp["total_timesteps"], "total_timesteps", where, minimum=1)
    for key in ("normalize_obs", "normalize_reward", "linear_lr_decay"):
        if key in hp and not isinstance(hp[key], bool):
            raise ValueError(f"{where}: {key} must be true or false, got {hp[key]!r}")
    for key in ("hidden_sizes", "hidden_sizes_masksembles"):
        if key in hp and not (is_atari(env_id) and hp[key] is None):
            check_widths(hp[key], key, where)
    check_algo_settings(hp["algo"], where)
    members = _check_mapping(hp.get("members") or {}, "members", where)
    check_keys(members, where, MEMBER_KEYS, what="member setting")
    check_member_values(members, where, prefix="members.")
    policy = _check_mapping(hp.get("policy") or {}, "policy", where)
    check_keys(policy, where, POLICY_KEYS, what="policy setting")
    if "activation_fn" in policy and policy["activation_fn"] not in ACTIVATIONS:
        raise ValueError(f"{where}: activation_fn={policy['activation_fn']!r}; use one of {sorted(ACTIVATIONS)}")
    if "log_std_init" in policy:
        check_number(policy["log_std_init"], "policy.log_std_init", where)
    if "ortho_init" in policy and not isinstance(policy["ortho_init"], bool):
        raise ValueError(f"{where}: policy.ortho_init must be true or false, got {policy['ortho_init']!r}")


def check_member_values(members: dict[str, Any], where: str, prefix: str = "", min_members: int = 2) -> None:
    """k an integer >= 2, p in [0, 1), the Masksembles scale in [1, 6]; None means "not given"."""
    if members.get("n_members") is not None:
        check_integer(members["n_members"], f"{prefix}n_members", where, minimum=min_members)
    if members.get("dropout_p") is not None:
        check_number(members["dropout_p"], f"{prefix}dropout_p", where, low=0.0, high=1.0, high_open=True)
    if members.get("masksembles_scale") is not None:
        check_number(members["masksembles_scale"], f"{prefix}masksembles_scale", where, low=1.0, high=6.0)


def policy_settings(hp: dict[str, Any], env_id: str) -> dict[str, Any]:
    """The table's `policy` entry as SB3 policy_kwargs (activation names -> classes).

    The paper's MuJoCo numbers are rl-baselines3-zoo's tuned entries, which come with these
    settings (log_std_init=-2, ortho_init=False, ReLU for HalfCheetah and Swimmer); member
    policies honour them exactly as `MlpPolicy` does.
    """
    raw = dict(check_keys(hp.get("policy") or {}, f"hyperparameters for {env_id}", POLICY_KEYS, what="policy setting"))
    if "activation_fn" in raw:
        if raw["activation_fn"] not in ACTIVATIONS:
            raise ValueError(f"hyperparameters for {env_id}: activation_fn={raw['activation_fn']!r}; "
                             f"use one of {sorted(ACTIVATIONS)}")
        raw["activation_fn"] = ACTIVATIONS[raw["activation_fn"]]
    return raw


def member_settings(hp: dict[str, Any], env_id: str, **explicit: Any) -> dict[str, Any]:
    """k, dropout p and Masksembles scale: an explicit argument wins over the table's `members`."""
    table = dict(check_keys(hp.get("members") or {}, f"hyperparameters for {env_id}", MEMBER_KEYS,
                            what="member setting"))
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


def resolve_run_config(
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
) -> dict[str, Any]:
    """The settings `make_agent` trains with (its `paper_lib_config`), checked, without building anything.

    What a run's config.json records, so a checkpoint can be compared with what a stage would train today
    (paper_lib.pipeline.landing) without an env or a network.
    """
    if algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algo!r}; use one of {sorted(ALGORITHMS)}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; use one of {METHODS}")
    if assignment not in ASSIGNMENTS:
        raise ValueError(f"unknown assignment {assignment!r}; use one of {ASSIGNMENTS}")
    if inference not in INFERENCE_MODES:
        raise ValueError(f"unknown inference mode {inference!r}; use one of {INFERENCE_MODES}")
    if not isinstance(env_id, str):
        raise ValueError(f"env_id must be a Gymnasium id string such as 'HalfCheetah-v5', got {env_id!r}")
    seed = check_seed(seed)  # a plain int from here on: gymnasium refuses numpy integers, json too
    hp = paper_hyperparameters(env_id) if hyperparameters is None else copy.deepcopy(hyperparameters)
    validate_hyperparameters(hp, env_id)
    check_member_values(dict(n_members=n_members, dropout_p=dropout_p, masksembles_scale=masksembles_scale), "make_agent",
                        min_members=1)  # k >= 2 is checked below for member methods, where it matters
    members = member_settings(hp, env_id, n_members=n_members, dropout_p=dropout_p, masksembles_scale=masksembles_scale)
    n_members, dropout_p, masksembles_scale = members["n_members"], members["dropout_p"], members["masksembles_scale"]
    mlp_settings = {} if is_atari(env_id) else policy_settings(hp, env_id)
    if overrides is not None and not isinstance(overrides, dict):
        raise ValueError(f"make_agent: overrides must be a dict of algorithm settings such as {{'n_steps': 64}}, "
                         f"got {overrides!r}")
    algo_kwargs = {**hp["algo"], **(overrides or {})}
    unknown = set(overrides or {}) - set(hp["algo"])
    if unknown:
        raise ValueError(f"unknown override(s) {sorted(unknown)}; known settings are {sorted(hp['algo'])}")
    check_algo_settings(overrides or {}, "make_agent", name="overrides", required=False)
    if ALGO_KEYS[algo] is not None:
        algo_kwargs = {k: v for k, v in algo_kwargs.items() if k in ALGO_KEYS[algo]}
    n_envs = hp["n_envs"] if n_envs is None else check_integer(n_envs, "n_envs", "make_agent", minimum=1)
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
                  normalize_reward=bool(hp.get("normalize_reward", False)),
                  policy=dict(hp.get("policy") or {}) if mlp_settings else {},
                  algo_kwargs=dict(algo_kwargs), linear_lr_decay=bool(hp.get("linear_lr_decay", False)),
                  total_timesteps=hp.get("total_timesteps"))

    return config


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
    env_processes: bool = False,
) -> BaseAlgorithm:
    """Build an SB3 model with the paper's hyperparameters for `env_id` and the given method.

    `hyperparameters` replaces the packaged table entry for `env_id` (the pipeline passes
    params.yaml's). `overrides` replaces entries of the algorithm settings (e.g. {"n_steps": 64}). Every
    input is checked before an env or network is built. The resolved settings are kept on the
    model as `model.paper_lib_config` and saved with it. `env_processes` steps the envs in
    subprocesses (see `make_env`): the same transitions, for many-core machines.
    """
    check_device(device)
    config = resolve_run_config(algo, method, env_id, seed, n_members=n_members, assignment=assignment,
                                inference=inference, dropout_p=dropout_p, masksembles_scale=masksembles_scale,
                                n_envs=n_envs, overrides=overrides, hyperparameters=hyperparameters)
    hp = paper_hyperparameters(env_id) if hyperparameters is None else copy.deepcopy(hyperparameters)
    mlp_settings = {} if is_atari(env_id) else policy_settings(hp, env_id)
    seed, n_envs, n_members = config["seed"], config["n_envs"], config["n_members"]
    dropout_p, masksembles_scale, hidden = config["dropout_p"], config["masksembles_scale"], config["hidden_sizes"]
    algo_kwargs = dict(config["algo_kwargs"])

    if env is None:
        env = make_env(env_id, n_envs, seed, normalize_obs=hp["normalize_obs"],
                       normalize_reward=config["normalize_reward"], gamma=algo_kwargs["gamma"],
                       env_processes=env_processes)
    elif env.num_envs != n_envs:
        raise ValueError(f"the given env has {env.num_envs} envs but n_envs={n_envs}")
    else:
        check_given_env(env, env_id)
        if method != "baseline":
            check_groups_match(env, n_members)
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
