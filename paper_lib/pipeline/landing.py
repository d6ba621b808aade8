"""Is a checkpoint the run its `train` stage would train today? Asked before a run trained outside DVC lands.

`scripts/land_run.sh` records a run trained by `scripts/train_queue.sh` as the output of its `train` stage
(`dvc commit`): from then on DVC vouches that the checkpoint is what params.yaml trains. That holds only if the
run was trained with the settings params.yaml gives it now: the env's recipe (`hyperparameters`), the profile's
overrides, inference mode and budget. A run trained under `retraining` before its entry moved, a probe copied
into the wrong folder, a run of the old budget: each is refused here, naming every setting that differs. The
same comparison runs over every committed checkpoint in the tests, so no table reads a run of another recipe.

    python -m paper_lib.pipeline.landing ENV METHOD SEED [ENV METHOD SEED ...]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from paper_lib.agents.factory import config_value, resolve_run_config
from paper_lib.pipeline.config import RunConfig, load_run_config

#: The settings that make a run what it is (config.json keys); wall time, machine and versions may differ.
TRAINING_KEYS = ("algo", "method", "env_id", "seed", "n_envs", "n_members", "dropout_p", "masksembles_scale",
                 "hidden_sizes", "normalize_obs", "normalize_reward", "policy", "algo_kwargs", "linear_lr_decay",
                 "total_timesteps")


def expected_for(env_id: str, method: str, seed: int, total_timesteps: int | None,
                 agent_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The config.json `train_run(env_id, method, seed, ..., total_timesteps, agent_kwargs)` would write."""
    config = resolve_run_config("ppo", method, env_id, seed, **agent_kwargs)
    return {**config, "total_timesteps": total_timesteps or config["total_timesteps"]}


def expected_config(cfg: RunConfig, env_id: str, method: str, seed: int) -> dict[str, Any]:
    """The config.json the profile's `train` stage would write for this run (paper_lib.pipeline.stages.train_stage)."""
    if env_id not in cfg.hyperparameters:
        raise ValueError(f"params.yaml has no hyperparameters for {env_id!r}; known: {sorted(cfg.hyperparameters)}")
    return expected_for(env_id, method, seed, cfg.budget(env_id),
                        {"hyperparameters": cfg.hyperparameters[env_id], "overrides": cfg.overrides or None,
                         "inference": cfg.inference})


def trained_config(folder: Path) -> dict[str, Any]:
    """A finished run's config.json (train_run writes model.zip and config.json only when a run completes)."""
    for name in ("model.zip", "config.json"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"{folder / name} is missing: the run has not finished training")
    return json.loads((folder / "config.json").read_text())


def differences(trained: dict[str, Any], expected: dict[str, Any]) -> list[str]:
    """Every training setting in which `trained` (a config.json) differs from `expected`, as text."""
    wrong = []
    for key in TRAINING_KEYS:
        have, want = config_value(trained, key), expected[key]
        if isinstance(have, dict) and isinstance(want, dict):  # name the entries that differ, not the whole dict
            wrong += [f"{key}.{k}: trained with {have.get(k)!r}, params.yaml gives {want.get(k)!r}"
                      for k in sorted(set(have) | set(want)) if have.get(k) != want.get(k)]
        elif have != want:
            wrong.append(f"{key}: trained with {have!r}, params.yaml gives {want!r}")
    steps = trained.get("trained_timesteps")
    if steps is not None and steps < expected["total_timesteps"]:
        wrong.append(f"trained_timesteps: {steps}, fewer than the budget {expected['total_timesteps']}")
    return wrong


def mismatches(cfg: RunConfig, env_id: str, method: str, seed: int, folder: Path | None = None) -> list[str]:
    """Every training setting in which the run's checkpoint differs from what params.yaml trains, as text."""
    trained = trained_config(folder or cfg.checkpoint_dir(env_id, method, seed))
    return differences(trained, expected_config(cfg, env_id, method, seed))


def check_landing(cfg: RunConfig, env_id: str, method: str, seed: int) -> None:
    """Raise one ValueError naming every differing setting and both ways to fix it, or return."""
    wrong = mismatches(cfg, env_id, method, seed)
    if wrong:
        folder = cfg.checkpoint_dir(env_id, method, seed)
        raise ValueError(
            f"{folder} was not trained as params.yaml trains {env_id} {method} seed {seed} (profile "
            f"{cfg.profile}):\n  " + "\n  ".join(wrong) + "\nIf the run is right and params.yaml is behind (an env "
            f"still under `retraining`, a profile budget not yet raised), update params.yaml first; otherwise "
            f"retrain the run with the settings params.yaml gives.")


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if not args or len(args) % 3:
        sys.exit("usage: python -m paper_lib.pipeline.landing ENV METHOD SEED [ENV METHOD SEED ...]")
    cfg = load_run_config()
    problems = []
    for i in range(0, len(args), 3):
        env_id, method, seed = args[i], args[i + 1], int(args[i + 2])
        try:
            check_landing(cfg, env_id, method, seed)
            print(f"ok {env_id} {method} seed {seed}: trained as params.yaml says")
        except (ValueError, FileNotFoundError) as err:
            problems.append(f"error: {err}")
    if problems:
        sys.exit("\n".join(problems))


if __name__ == "__main__":
    main()
