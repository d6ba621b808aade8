"""Pipeline stage commands that are not notebooks (DVC calls them; see dvc.yaml).

    python -m paper_lib.pipeline collect HalfCheetah-v5 masksembles 0
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch as th

from paper_lib.checkpoints import load_checkpoint
from paper_lib.config import RunConfig, load_run_config
from paper_lib.envs import is_atari
from paper_lib.ood.collect import ActionMode, collect_atari_ood_states, collect_id_states, collect_mujoco_ood_states
from paper_lib.ood.datasets import concat


def collect_run(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """ID and OOD states of one trained run, with the profile's action mode, saved as one dataset."""
    th.set_num_threads(1)
    ckpt = load_checkpoint(cfg.checkpoint_dir(env_id, method, seed), env_id, method, seed)
    vecnormalize = ckpt.env(1, seed) if ckpt.vecnormalize_path is not None else None
    mode = ActionMode(deterministic=cfg.deterministic, inference=cfg.inference)
    common = dict(action_mode=mode, max_episode_steps=cfg.max_episode_steps, skip_first=cfg.skip_first,
                  vecnormalize=vecnormalize)
    id_states = collect_id_states(ckpt.model, env_id, cfg.n_id_states, seed=1000 * seed + 1, **common)
    if is_atari(env_id):
        common.pop("vecnormalize")
        ood_states = collect_atari_ood_states(ckpt.model, env_id, cfg.n_ood_states, seed=1000 * seed + 2, **common)
    else:
        ood_states = collect_mujoco_ood_states(ckpt.model, env_id, cfg.n_ood_states, seed=1000 * seed + 2, **common)
    return concat(id_states, ood_states).save(cfg.dataset_path(env_id, method, seed))


def main() -> None:
    parser = argparse.ArgumentParser(description="Pipeline stages that are not notebooks.")
    sub = parser.add_subparsers(dest="stage", required=True)
    collect = sub.add_parser("collect", help="collect one run's ID and OOD states")
    collect.add_argument("env_id")
    collect.add_argument("method")
    collect.add_argument("seed", type=int)
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args()
    cfg = load_run_config(args.params)
    print(collect_run(cfg, args.env_id, args.method, args.seed))


if __name__ == "__main__":
    main()
