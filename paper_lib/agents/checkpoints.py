"""Loading a training run's checkpoint folder, with one clear error for each way it can be wrong.

A checkpoint is trusted on what its files are, not on their names: model.zip's own policy (class,
method, k, widths, seed) and algorithm must match config.json and the stage's env/method/seed, and
vecnormalize.pkl must be present exactly when the run normalized observations. SB3 reads a zip's
saved data without building the model (`load_from_zip_file`), so every check runs before loading.
"""

from __future__ import annotations

import json
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import VecEnv, VecNormalize, VecTransposeImage

from paper_lib.agents.envs import make_env, normalizer_env_id
from paper_lib.agents.factory import ACTIVATIONS, ALGORITHMS
from paper_lib.methods.policy import MemberActorCriticPolicy


@dataclass
class Checkpoint:
    """A trained model, its observation normalizer (if any) and the config it was trained with."""

    model: BaseAlgorithm
    config: dict[str, Any]
    vecnormalize_path: Path | None
    folder: Path

    def env(self, n_envs: int, seed: int, env_kwargs: dict[str, Any] | None = None) -> VecEnv:
        """A fresh env like the training one; observation statistics frozen from training."""
        venv = make_env(self.config["env_id"], n_envs, seed, env_kwargs=env_kwargs)
        if self.vecnormalize_path is not None:
            venv = VecNormalize.load(str(self.vecnormalize_path), venv)
            venv.training, venv.norm_reward = False, False
        return venv

    def training_curve(self) -> pd.DataFrame:
        return pd.read_csv(self.folder / "training_curve.csv")


#: Algorithms paper_lib does not load, by the SB3 / sb3-contrib module their policy class lives in.
FOREIGN_POLICY_MODULES = {"dqn": "DQN", "sac": "SAC", "td3": "TD3 (or DDPG)", "qrdqn": "QR-DQN", "tqc": "TQC",
                          "crossq": "CrossQ", "ars": "ARS"}
#: Settings only off-policy algorithms (a replay buffer) save.
OFF_POLICY_KEYS = ("replay_buffer_class", "buffer_size", "learning_starts")


def foreign_algorithm(data: dict[str, Any]) -> str | None:
    """The algorithm that saved this model data when it is not one paper_lib loads, else None.

    DQN saves `n_steps` too, so without this a DQN zip passes for A2C and fails deep inside SB3;
    the policy class's module and the replay-buffer settings tell the algorithms apart.
    """
    policy_class = data.get("policy_class")
    name = getattr(policy_class, "__name__", None)
    package, _, rest = str(getattr(policy_class, "__module__", "")).partition(".")
    if package in ("stable_baselines3", "sb3_contrib") and rest.split(".")[0] in FOREIGN_POLICY_MODULES:
        return FOREIGN_POLICY_MODULES[rest.split(".")[0]]
    for prefix in ("Recurrent", "Maskable"):  # sb3-contrib's PPO variants save PPO's settings
        if name is not None and name.startswith(prefix):
            return f"{prefix}PPO"
    if any(key in data for key in OFF_POLICY_KEYS):
        return f"an off-policy algorithm (policy {name or 'unknown'})"
    return None


def check_loadable_algorithm(data: dict[str, Any], zip_path: Path) -> None:
    """One clear error for a zip of an algorithm paper_lib does not load, before SB3 fails on it."""
    foreign = foreign_algorithm(data)
    if foreign is not None:
        raise ValueError(f"{zip_path} holds a model paper_lib cannot load, got {foreign}; paper_lib loads "
                         f"{', '.join(name.upper() for name in sorted(ALGORITHMS))} models (algo one of "
                         f"{sorted(ALGORITHMS)}): load this one with its own SB3 class, or train the agent "
                         "with one of those")


def zip_algorithm(data: dict[str, Any]) -> str | None:
    """Which of paper_lib's algorithms saved this model data, from the settings only it has.

    SB3 saves an algorithm's attributes, not its class: TRPO alone has `cg_max_steps`, PPO alone
    (of the three) `clip_range` and `n_epochs`, and A2C has `n_steps` but neither. None for
    any other algorithm (`foreign_algorithm` names it).
    """
    if foreign_algorithm(data) is not None:
        return None
    if "cg_max_steps" in data:
        return "trpo"
    if "clip_range" in data and "n_epochs" in data:
        return "ppo"
    if "n_steps" in data:
        return "a2c"
    return None


def policy_identity(data: dict[str, Any]) -> dict[str, Any]:
    """What the zip's own saved policy is: method, k, hidden widths, member seed, activation."""
    policy_class, kwargs = data.get("policy_class"), dict(data.get("policy_kwargs") or {})
    if isinstance(policy_class, type) and issubclass(policy_class, MemberActorCriticPolicy):
        hidden = kwargs.get("hidden_sizes")
        return {"method": kwargs.get("method", "masksembles"), "n_members": kwargs.get("n_members", 4),
                "hidden_sizes": None if hidden is None else list(hidden), "seed": kwargs.get("member_seed", 0),
                "activation_fn": kwargs.get("activation_fn")}
    if isinstance(policy_class, type) and issubclass(policy_class, ActorCriticPolicy):
        arch = kwargs.get("net_arch")
        hidden = arch.get("pi") if isinstance(arch, dict) else arch
        return {"method": "baseline", "hidden_sizes": None if hidden is None else list(hidden),
                "activation_fn": kwargs.get("activation_fn")}
    return {"method": None, "class": getattr(policy_class, "__name__", repr(policy_class))}


def _mismatches(ident: dict[str, Any], algo: str | None, data: dict[str, Any], config: dict[str, Any]) -> list[str]:
    """`what the zip has` vs `what config.json says`, for each setting that identifies a run."""
    found = []
    expected_algo = config.get("algo", "ppo")
    if algo != expected_algo:
        found.append(f"algorithm {algo!r} (config.json: {expected_algo!r})")
    if ident["method"] is None:
        return found + [f"policy class {ident['class']} (not a paper_lib or SB3 actor-critic policy)"]
    if ident["method"] != config.get("method"):
        found.append(f"method {ident['method']!r} (config.json: {config.get('method')!r})")
        return found  # the other settings follow from the method
    if ident["method"] != "baseline" and ident["n_members"] != config.get("n_members"):
        found.append(f"k={ident['n_members']} members (config.json: n_members={config.get('n_members')!r})")
    hidden = config.get("hidden_sizes")
    if ident["hidden_sizes"] is not None and hidden is not None and ident["hidden_sizes"] != list(hidden):
        found.append(f"hidden widths {ident['hidden_sizes']} (config.json: {list(hidden)})")
    seeds = {data.get("seed"), ident.get("seed", data.get("seed"))} - {None}
    if "seed" in config and seeds and seeds != {config["seed"]}:
        found.append(f"seed {sorted(seeds)} (config.json: {config['seed']!r})")
    activation = (config.get("policy") or {}).get("activation_fn")
    if activation in ACTIVATIONS and ident["activation_fn"] not in (None, ACTIVATIONS[activation]):
        found.append(f"activation {ident['activation_fn'].__name__} (config.json: {activation!r})")
    return found


def _check_spaces(zip_path: Path, data: dict[str, Any], env_id: Any, retrain: str) -> None:
    """The zip's observation and action spaces are those of the env config.json names."""
    if not isinstance(env_id, str):
        raise ValueError(f"{zip_path.parent / 'config.json'} names no env_id; {retrain}")
    try:
        venv = make_env(env_id, 1, 0)
    except Exception as err:  # an env id gymnasium does not know
        raise ValueError(f"{zip_path.parent / 'config.json'} names env {env_id!r}, which cannot be made "
                         f"({type(err).__name__}: {err}); {retrain}") from None
    observations = venv.observation_space
    if is_image_space(observations) and not is_image_space_channels_first(observations):
        observations = VecTransposeImage.transpose_space(observations)  # as SB3 wraps image envs
    try:
        for name, space in (("observation", observations), ("action", venv.action_space)):
            saved = data.get(f"{name}_space")
            if saved is not None and (type(saved) is not type(space) or saved.shape != space.shape
                                      or getattr(saved, "n", None) != getattr(space, "n", None)):
                raise ValueError(f"{zip_path} takes {name}s {saved} but {env_id} has {space}: the model was "
                                 f"trained on another env; {retrain}")
    finally:
        venv.close()


def _check_normalizer(norm: Path, config: dict[str, Any], data: dict[str, Any], retrain: str) -> Path | None:
    """vecnormalize.pkl exactly when the run normalized, and then a VecNormalize of the model's observations."""
    normalized = bool(config.get("normalize_obs")) or bool(config.get("normalize_reward"))
    if not normalized:
        if norm.exists():
            raise ValueError(f"{norm} is present but {norm.parent / 'config.json'} says normalize_obs: false "
                             "(and no normalize_reward), so "
                             "it does not belong to this run and would be applied by mistake; delete it, or "
                             f"{retrain}")
        return None
    if not norm.is_file():
        raise FileNotFoundError(f"{norm} is missing but the run normalized observations; {retrain}")
    try:
        with open(norm, "rb") as f:
            saved = pickle.load(f)
    except Exception as err:  # a truncated or foreign pickle: name the file, not a deep traceback
        raise ValueError(f"{norm} is not a readable observation normalizer ({type(err).__name__}: {err}); "
                         f"{retrain}") from None
    space = data.get("observation_space")
    if not isinstance(saved, VecNormalize):
        raise ValueError(f"{norm} holds a {type(saved).__name__}, not a VecNormalize; {retrain}")
    recorded = normalizer_env_id(saved)
    if recorded is not None and recorded != config.get("env_id"):
        raise ValueError(f"{norm} was saved for {recorded} but {norm.parent / 'config.json'} says "
                         f"{config.get('env_id')}: another run's normalizer was put here; {retrain}")
    shape = getattr(getattr(saved, "obs_rms", None), "mean", None)
    if space is not None and shape is not None and tuple(shape.shape) != tuple(space.shape):
        raise ValueError(f"{norm} normalizes observations of shape {tuple(shape.shape)} but model.zip takes "
                         f"{tuple(space.shape)}; {retrain}")
    return norm


def load_checkpoint(folder: str | Path, env_id: str | None = None, method: str | None = None,
                    seed: int | None = None) -> Checkpoint:
    """Load `folder`, checking it was trained for the env, method and seed the caller expects.

    config.json is checked against the caller's env/method/seed, and model.zip's saved policy and
    algorithm against config.json, before the model is built.
    """
    folder = Path(folder)
    stage = f"train@{env_id}-{method}-{seed}" if None not in (env_id, method, seed) else "train@<env>-<method>-<seed>"
    retrain = f"retrain it explicitly with `dvc repro -f -s {stage}` or restore it with `git checkout {folder}`"
    for name in ("model.zip", "config.json"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"checkpoint file {folder / name} is missing; {retrain}")
    try:
        config = json.loads((folder / "config.json").read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{folder / 'config.json'} is not valid JSON ({err}); {retrain}") from None
    if not isinstance(config, dict):
        raise ValueError(f"{folder / 'config.json'} is not a JSON object; {retrain}")
    for key, expected in (("env_id", env_id), ("method", method), ("seed", seed)):
        if expected is not None and config.get(key) != expected:
            raise ValueError(f"checkpoint {folder} was trained with {key}={config.get(key)!r} but this stage expects "
                             f"{expected!r}; {retrain}")
    algo = ALGORITHMS.get(config.get("algo", "ppo"))
    if algo is None:
        raise ValueError(f"{folder / 'config.json'} names an unknown algorithm {config.get('algo')!r}; {retrain}")
    zip_path = folder / "model.zip"
    try:
        data, _, _ = load_from_zip_file(zip_path, device="cpu")
    except Exception as err:  # a truncated or foreign zip: say which file, not a deep traceback
        raise ValueError(f"cannot load {zip_path} ({type(err).__name__}: {err}); {retrain}") from None
    if not isinstance(data, dict):
        raise ValueError(f"cannot load {zip_path} (it holds no model data); {retrain}")
    check_loadable_algorithm(data, zip_path)
    wrong = _mismatches(policy_identity(data), zip_algorithm(data), data, config)
    if wrong:
        raise ValueError(f"{zip_path} does not belong to {folder / 'config.json'}: the model has {'; '.join(wrong)}. "
                         f"A model.zip from another run was put here; {retrain}")
    _check_spaces(zip_path, data, config.get("env_id"), retrain)
    norm = _check_normalizer(folder / "vecnormalize.pkl", config, data, retrain)
    try:
        model = algo.load(zip_path, device="cpu")
    except Exception as err:  # weights that do not fit the saved policy
        raise ValueError(f"cannot load {zip_path} ({type(err).__name__}: {err}); {retrain}") from err
    return Checkpoint(model, config, norm, folder)
