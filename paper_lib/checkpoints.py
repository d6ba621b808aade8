"""Loading a training run's checkpoint folder, with one clear error for each way it can be wrong."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from paper_lib.agents import ALGORITHMS
from paper_lib.envs import make_env


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


def load_checkpoint(folder: str | Path, env_id: str | None = None, method: str | None = None,
                    seed: int | None = None) -> Checkpoint:
    """Load `folder`, checking it was trained for the env, method and seed the caller expects."""
    folder = Path(folder)
    retrain = f"retrain it explicitly with `dvc repro -f -s train@{env_id}-{method}-{seed}` or restore it with `git checkout {folder}`"
    for name in ("model.zip", "config.json"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"checkpoint file {folder / name} is missing; {retrain}")
    try:
        config = json.loads((folder / "config.json").read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{folder / 'config.json'} is not valid JSON ({err}); {retrain}") from None
    for key, expected in (("env_id", env_id), ("method", method), ("seed", seed)):
        if expected is not None and config.get(key) != expected:
            raise ValueError(f"checkpoint {folder} was trained with {key}={config.get(key)!r} but this stage expects "
                             f"{expected!r}; {retrain}")
    algo = ALGORITHMS.get(config.get("algo", "ppo"))
    if algo is None:
        raise ValueError(f"{folder / 'config.json'} names an unknown algorithm {config.get('algo')!r}")
    try:
        model = algo.load(folder / "model.zip", device="cpu")
    except Exception as err:  # a truncated or foreign zip: say which file, not a deep traceback
        raise ValueError(f"cannot load {folder / 'model.zip'} ({type(err).__name__}: {err}); {retrain}") from err
    norm = folder / "vecnormalize.pkl"
    if config.get("normalize_obs") and not norm.is_file():
        raise FileNotFoundError(f"{norm} is missing but the run normalized observations; {retrain}")
    return Checkpoint(model, config, norm if norm.is_file() else None, folder)
