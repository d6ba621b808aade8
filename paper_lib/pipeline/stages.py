"""Pipeline stages of one run that are not notebooks (DVC calls them; see dvc.yaml).

    python -m paper_lib.pipeline.stages collect HalfCheetah-v5 masksembles 0

`train_stage` trains a run of the active profile (notebook 1, the `train` stage, calls it); the one training
command line is `python -m paper_lib.agents.training` (any run, the packaged hyperparameters and `--hp` edits).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.agents.envs import is_atari
from paper_lib.agents.training import stage_lock
from paper_lib.ood.atari_head import atari_head_ood_dataset
from paper_lib.ood.collect import ActionMode, collect_atari_ood_states, collect_id_states, collect_mujoco_ood_states
from paper_lib.ood.datasets import StateDataset, concat
from paper_lib.pipeline.config import RunConfig, load_run_config


def train_stage(cfg: RunConfig, env_id: str, method: str, seed: int, **train_kwargs) -> Path:
    """Train one run of the active profile into its checkpoint folder (what notebook 1 runs).

    Uses params.yaml's hyperparameters, overrides, budget and inference mode, and resumes from
    the run's last resume point when one exists.
    """
    from paper_lib.agents.training import train_run

    if env_id not in cfg.hyperparameters:
        raise ValueError(f"params.yaml has no hyperparameters for {env_id!r}; known: {sorted(cfg.hyperparameters)}")
    agent_kwargs = {"hyperparameters": cfg.hyperparameters[env_id], "overrides": cfg.overrides or None,
                    "inference": cfg.inference}
    return train_run(env_id, method, seed, cfg.checkpoint_dir(env_id, method, seed), total_timesteps=cfg.budget(env_id),
                     agent_kwargs=agent_kwargs, **train_kwargs)


def collect_states(cfg: RunConfig, model: BaseAlgorithm, env_id: str, seed: int,
                   vecnormalize: VecNormalize | None = None) -> StateDataset:
    """ID and OOD states of one agent with the profile's action mode and protocol (ID first).

    protocol "main" (section 5): id_episodes and ood_configs clusters of steps_per_config states
    each; "appendix" (appendix G): n_id_states and n_ood_states, a new configuration per episode.
    Atari OOD states are edited game states, or, where params.yaml gives `atari_head.root`, as
    many frames of human play from that Atari-HEAD copy.
    """
    th.set_num_threads(1)
    mode = ActionMode(deterministic=cfg.deterministic, inference=cfg.inference)
    common = dict(action_mode=mode, max_episode_steps=cfg.max_episode_steps, skip_first=cfg.skip_first)
    if cfg.protocol == "main":
        id_size = dict(episodes=cfg.id_episodes, steps_per_episode=cfg.steps_per_config)
        ood_size = dict(configs=cfg.ood_configs, steps_per_config=cfg.steps_per_config)
        n_ood = cfg.ood_configs * cfg.steps_per_config
    else:
        id_size, ood_size = dict(n_states=cfg.n_id_states), dict(n_states=cfg.n_ood_states)
        n_ood = cfg.n_ood_states
    id_states = collect_id_states(model, env_id, seed=1000 * seed + 1, vecnormalize=vecnormalize, **id_size, **common)
    if is_atari(env_id) and cfg.atari_head_root is not None:
        ood_states = atari_head_ood_dataset(cfg.atari_head_root, env_id, n_ood, seed=1000 * seed + 2)
    elif is_atari(env_id):
        ood_states = collect_atari_ood_states(model, env_id, seed=1000 * seed + 2, **ood_size, **common)
    else:
        ood_states = collect_mujoco_ood_states(model, env_id, seed=1000 * seed + 2, vecnormalize=vecnormalize,
                                               **ood_size, **common)
    return concat(id_states, ood_states)


def collect_run(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """`collect_states` of one trained run of the active profile, saved as its dataset."""
    ckpt = load_checkpoint(cfg.checkpoint_dir(env_id, method, seed), env_id, method, seed)
    vecnormalize = ckpt.env(1, seed) if ckpt.vecnormalize_path is not None else None
    path = cfg.dataset_path(env_id, method, seed)
    with stage_lock(path, "collecting"):
        return collect_states(cfg, ckpt.model, env_id, seed, vecnormalize).save(path)


def main() -> None:
    parser = argparse.ArgumentParser(description="Collect one run's ID and OOD states (the `collect` stage).")
    parser.add_argument("stage", choices=["collect"], help="the stage (training: notebook 1 or paper_lib.agents.training)")
    parser.add_argument("env_id")
    parser.add_argument("method")
    parser.add_argument("seed", type=int)
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args()
    try:  # a bad input is one line naming the problem, not a traceback
        print(collect_run(load_run_config(args.params), args.env_id, args.method, args.seed))
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")


if __name__ == "__main__":
    main()
