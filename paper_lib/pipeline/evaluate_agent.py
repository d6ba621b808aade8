"""Bring your own agent: the benchmark's OOD metrics for any SB3 PPO, A2C or TRPO checkpoint.

    python -m paper_lib.pipeline.evaluate_agent path/to/model.zip HalfCheetah-v5 [--vecnormalize vecnormalize.pkl] [--out DIR]

The checkpoint may hold a member policy (Masksembles, MC Dropout, MC DropConnect, Ensemble:
every member measure is scored) or a plain `MlpPolicy` / `CnnPolicy` (the member-free
detectors, and `max_prob` / `entropy` for discrete actions). The agent acts in the default
env for the ID states and in the benchmark's perturbed envs (MuJoCo physics, Atari game
states) for the OOD states, with the main text's protocol (configurations x steps, ID
episodes x steps) at a budget you choose; a noise OOD set is made from the ID states. The
result is one row per (OOD set, measure or detector): AUROC with a cluster-bootstrap 95% CI,
AUPR-in/out, FPR@95 (OpenOOD's: ID states flagged when 95% of OOD states are caught) and
detection error, OOD positive.
"""

from __future__ import annotations

import argparse
import os
import pickle
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import VecNormalize

from paper_lib.agents.checkpoints import check_loadable_algorithm, zip_algorithm
from paper_lib.agents.envs import is_atari, make_env, normalizer_env_id, wrapped_env_ids
from paper_lib.agents.factory import ALGORITHMS, check_device
from paper_lib.common.io import (MixedFilesError, atomic_dir, atomic_files, check_folder_destination, recover_files,
                                 write_text_atomic)
from paper_lib.ood.atari import ATARI_GAMES
from paper_lib.ood.collect import ActionMode, collect_atari_ood_states, collect_id_states, collect_mujoco_ood_states
from paper_lib.ood.datasets import StateDataset, concat
from paper_lib.ood.mujoco import SUPPORTED_ENVS
from paper_lib.reporting.tables import save_table
from paper_lib.scoring.ood_scores import METRICS_NOTE, RunScores, score_run

SUPPORTED = (*SUPPORTED_ENVS, *(f"{game}NoFrameskip-v4" for game in ATARI_GAMES))


@dataclass(frozen=True)
class Budget:
    """How many states: the main text's protocol at a size the caller picks (defaults: the paper's)."""

    configs: int = 50
    steps_per_config: int = 100
    id_episodes: int = 20
    skip_first: int = 10
    max_episode_steps: int = 500
    n_bootstrap: int = 1000
    n_scoring_seeds: int = 5

    def __post_init__(self) -> None:
        for name in ("configs", "steps_per_config", "id_episodes", "max_episode_steps", "n_bootstrap",
                     "n_scoring_seeds"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name}={value!r}: need a positive integer.")
        if self.id_episodes < 2:
            raise ValueError(f"id_episodes={self.id_episodes}: the detectors are fitted on half of the ID episodes "
                             "and evaluated on the other half; give at least 2.")
        if not 0 <= self.skip_first < self.max_episode_steps:
            raise ValueError(f"skip_first={self.skip_first!r}, max_episode_steps={self.max_episode_steps!r}: need "
                             "0 <= skip_first < max_episode_steps.")

    def caption(self) -> str:
        return (f"main-text protocol at this budget: OOD states from {self.configs} configurations x "
                f"{self.steps_per_config} steps, ID states from {self.id_episodes} episodes x {self.steps_per_config} "
                f"steps, first {self.skip_first} states of each episode dropped")


@dataclass
class AgentEvaluation:
    metrics: pd.DataFrame  # one row per (ood_set, measure or detector)
    dataset: StateDataset  # the collected ID and OOD states
    scores: RunScores  # per-state scores, ROC points and bootstrap replicates


def load_agent(model_path: str | Path, algo: str | None = None, device: str = "cpu") -> BaseAlgorithm:
    """Any SB3 PPO / A2C / TRPO zip; the algorithm is read from the zip's settings unless given."""
    path = Path(model_path)
    if not path.is_file():
        raise FileNotFoundError(f"no model at {path}: give the .zip that model.save() wrote")
    if algo is not None and algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algo!r}; use one of {sorted(ALGORITHMS)}")
    check_device(device, "load_agent")
    try:
        data, _, _ = load_from_zip_file(path, device="cpu", load_data=True)
    except Exception as err:  # not a zip, or not SB3's
        raise ValueError(f"{path} is not an SB3 model zip ({type(err).__name__}: {err})") from err
    check_loadable_algorithm(data or {}, path)  # even with algo given: a DQN zip fails deep in SB3 otherwise
    if algo is None:
        algo = zip_algorithm(data or {})
        if algo is None:
            raise ValueError(f"{path}: cannot tell which algorithm saved it; pass algo= one of {sorted(ALGORITHMS)}")
    try:
        return ALGORITHMS[algo].load(path, device=device)
    except Exception as err:
        raise ValueError(f"cannot load {path} as {algo} ({type(err).__name__}: {err})") from err


def load_vecnormalize(path: str | Path, env_id: str, seed: int) -> VecNormalize:
    """The observation normalizer saved with the agent, frozen (as SB3's docs advise for evaluation)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no VecNormalize at {path}: give the .pkl that VecNormalize.save() wrote")
    try:
        with open(path, "rb") as f:
            venv = pickle.load(f)  # what VecNormalize.load does, with the env check in between
        if not isinstance(venv, VecNormalize):
            raise TypeError(f"it holds a {type(venv).__name__}")
    except Exception as err:
        raise ValueError(f"cannot load {path} as a VecNormalize for {env_id} ({type(err).__name__}: {err})") from err
    check_vecnormalize(venv, env_id, str(path))
    check_recorded_env(venv, env_id, path)
    venv.set_venv(make_env(env_id, 1, seed))
    venv.training, venv.norm_reward = False, False
    return venv


def check_recorded_env(vecnormalize: VecNormalize, env_id: str, path: Path) -> None:
    """A pkl saved by paper_lib records its env: another env's is refused. An older one (or SB3's own) cannot say,
    so it is accepted with a warning: a normalizer of another env with the same observation shape would pass."""
    recorded = normalizer_env_id(vecnormalize)
    if recorded is None:
        warnings.warn(f"{path} records no env id (saved before paper_lib recorded one, or by plain SB3): it is taken "
                      f"to be {env_id}'s; a normalizer of another env with observations of the same shape would be "
                      "applied without a word. Check it is the one the agent was trained with", stacklevel=3)
    elif recorded != env_id:
        raise ValueError(f"{path} was saved for {recorded}, but the agent is evaluated on {env_id}: give the "
                         f"VecNormalize the agent was trained with on {env_id}")


def check_vecnormalize(vecnormalize: VecNormalize, env_id: str, where: str = "the VecNormalize") -> None:
    """A normalizer of another env would scale the agent's observations with another env's statistics (or fail deep
    in numpy mid-collection): refuse it before any rollout, naming both envs. A saved one holds no env id, so
    of two envs with observations of one shape (HalfCheetah, Walker2d: 17) only an in-memory one is told apart."""
    env = make_env(env_id, 1, 0)
    shape = env.observation_space.shape
    env.close()
    if vecnormalize.observation_space.shape != shape:
        raise ValueError(f"{where} normalizes observations of shape {vecnormalize.observation_space.shape}, but "
                         f"{env_id}'s have shape {shape}: it belongs to another env; give the VecNormalize the agent "
                         f"was trained with on {env_id}")
    wrapped = getattr(vecnormalize, "venv", None)
    ids = wrapped_env_ids(wrapped) if wrapped is not None else []
    if ids and ids != [env_id]:
        raise ValueError(f"{where} wraps {', '.join(ids)}, but the agent is evaluated on {env_id}: give the "
                         f"VecNormalize the agent was trained with on {env_id}")


def evaluate_agent(model: BaseAlgorithm | str | Path, env_id: str, *,
                   vecnormalize: VecNormalize | str | Path | None = None, budget: Budget = Budget(), seed: int = 0,
                   deterministic: bool = False, algo: str | None = None,
                   out_dir: str | Path | None = None) -> AgentEvaluation:
    """Collect ID and OOD states with the agent and score them with every measure and detector it has.

    ``model`` is an SB3 model or the path of its zip; ``vecnormalize`` the VecNormalize (or its
    .pkl) it was trained with, if it was. Actions are sampled unless ``deterministic``; a member
    policy combines its members by vote. With ``out_dir``, the dataset, the metrics table
    (csv, md, tex) and the ROC points are written there.
    """
    if env_id not in SUPPORTED:
        raise ValueError(f"no OOD states exist for {env_id!r}: the benchmark perturbs {list(SUPPORTED)}")
    if not isinstance(budget, Budget):
        raise TypeError(f"budget must be a Budget (e.g. Budget(configs=10, steps_per_config=50)), got "
                        f"{type(budget).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r}: need a non-negative int.")
    if out_dir is not None:  # before the collection: a wrong --out must not cost the whole run
        check_output_folder(out_dir)
    agent = model if isinstance(model, BaseAlgorithm) else load_agent(model, algo)
    if vecnormalize is not None and not isinstance(vecnormalize, VecNormalize):
        vecnormalize = load_vecnormalize(vecnormalize, env_id, seed)
    elif vecnormalize is not None:
        check_vecnormalize(vecnormalize, env_id)
    if out_dir is not None:  # every input checked: a write a kill stopped part-way gets its old files back now,
        recover_files(out_dir)  # not only after the collection
    mode = ActionMode(deterministic=deterministic, inference="vote")
    common = dict(action_mode=mode, max_episode_steps=budget.max_episode_steps, skip_first=budget.skip_first)
    with th.random.fork_rng(devices=[]):
        id_states = collect_id_states(agent, env_id, seed=2 * seed + 1, episodes=budget.id_episodes,
                                      steps_per_episode=budget.steps_per_config, vecnormalize=vecnormalize, **common)
        if is_atari(env_id):
            ood_states = collect_atari_ood_states(agent, env_id, seed=2 * seed + 2, configs=budget.configs,
                                                  steps_per_config=budget.steps_per_config, **common)
        else:
            ood_states = collect_mujoco_ood_states(agent, env_id, seed=2 * seed + 2, configs=budget.configs,
                                                   steps_per_config=budget.steps_per_config,
                                                   vecnormalize=vecnormalize, **common)
        dataset = concat(id_states, ood_states)
        scores = score_run(agent, dataset, seed, budget.n_bootstrap, n_scoring_seeds=budget.n_scoring_seeds,
                           vecnormalize=vecnormalize)
    metrics = scores.metrics.assign(env=env_id)
    result = AgentEvaluation(metrics, dataset, scores)
    if out_dir is not None:
        actions = "deterministic" if deterministic else "sampled"
        write_outputs(result, out_dir,
                      caption=f"OOD detection metrics of {type(agent).__name__} ({type(agent.policy).__name__}) on "
                              f"{env_id} ({budget.caption()}; {actions} actions; seed {seed}; {METRICS_NOTE}).")
    return result


class OutputWriteError(OSError):
    """The results could not be written (a full disk, a lost mount); the output folder was left as it was."""


#: What `write_outputs` puts into the output folder.
OUTPUT_FILES = ("dataset.npz", "ood_metrics.csv", "ood_metrics.md", "ood_metrics.tex", "roc.csv")


def check_output_folder(out_dir: str | Path) -> Path:
    """The --out folder must be writable and must not hold a folder where one of the output files goes."""
    out = check_folder_destination(out_dir, "--out folder")
    in_the_way = [name for name in OUTPUT_FILES if (out / name).is_dir()]
    if in_the_way:
        raise ValueError(f"--out folder {out} holds folders where output files go, got {in_the_way}; move them away "
                         "or give another --out folder")
    return out


def swapped_whole(out: Path) -> bool:
    """Whether `out` can be replaced as one folder: new, or holding this command's files only (a previous run's), as a
    real folder whose parent takes the new one beside it. Then a kill at any instant leaves the old files or the new
    ones, never a mix; a folder that also holds the user's files gets the group move (`atomic_files`) instead, whose
    journal puts the old files back at the next call, since swapping the folder would remove the user's files."""
    if out.is_symlink() or not os.access(out.parent, os.W_OK | os.X_OK):
        return False
    return not out.exists() or all(entry.name in OUTPUT_FILES and entry.is_file() and not entry.is_symlink()
                                   for entry in out.iterdir())


def write_outputs(result: AgentEvaluation, out_dir: str | Path, caption: str) -> Path:
    """Every output file written aside first and put in together: a failure part-way changes nothing in `out_dir`,
    and where the folder holds only these files it is swapped in whole (`swapped_whole`)."""
    out = check_output_folder(out_dir)
    try:
        with (atomic_dir(out) if swapped_whole(out) else atomic_files(out)) as stage:
            result.dataset.save(stage / "dataset.npz")
            save_table(result.metrics, stage / "ood_metrics", caption=caption)
            write_text_atomic(stage / "roc.csv", result.scores.roc.to_csv(index=False))
    except MixedFilesError as err:  # not "as it was": say what puts the old files back
        raise OutputWriteError(str(err)) from err
    except OSError as err:
        raise OutputWriteError(f"writing the results to {out} failed, got {type(err).__name__}: {err}; none of them "
                               f"was moved in, so {out} is as it was: free space or give another --out folder") from err
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="OOD metrics of any SB3 PPO/A2C/TRPO checkpoint on the paper's "
                                                 "benchmark (perturbed and noise OOD states).")
    parser.add_argument("model", help="the model's .zip (SB3 model.save)")
    parser.add_argument("env_id", help=f"one of {', '.join(SUPPORTED)}")
    parser.add_argument("--vecnormalize", help="the VecNormalize .pkl the agent was trained with, if any")
    parser.add_argument("--out", help="folder for dataset.npz, ood_metrics.{csv,md,tex} and roc.csv")
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), help="only if it cannot be read from the zip")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--deterministic", action="store_true", help="act with the mean / argmax action")
    defaults = Budget()
    parser.add_argument("--configs", type=int, default=defaults.configs, help="OOD configurations")
    parser.add_argument("--steps", type=int, default=defaults.steps_per_config,
                        help="kept states per configuration and per ID episode")
    parser.add_argument("--id-episodes", type=int, default=defaults.id_episodes)
    parser.add_argument("--skip-first", type=int, default=defaults.skip_first)
    parser.add_argument("--max-episode-steps", type=int, default=defaults.max_episode_steps)
    parser.add_argument("--bootstrap", type=int, default=defaults.n_bootstrap, help="bootstrap replicates")
    parser.add_argument("--scoring-seeds", type=int, default=defaults.n_scoring_seeds,
                        help="torch seeds an MC Dropout / DropConnect policy is scored under")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    try:
        budget = Budget(args.configs, args.steps, args.id_episodes, args.skip_first, args.max_episode_steps,
                        args.bootstrap, args.scoring_seeds)
        result = evaluate_agent(args.model, args.env_id, vecnormalize=args.vecnormalize, budget=budget, seed=args.seed,
                                deterministic=args.deterministic, algo=args.algo, out_dir=args.out)
    except (ValueError, FileNotFoundError, TypeError) as err:
        parser.exit(2, f"error: {err}\n")
    except OutputWriteError as err:  # e.g. a full disk while the results were written: none of them was moved in
        parser.exit(1, f"error: {err}\n")
    table = result.metrics.pivot_table(index="measure", columns="ood_set", values="auroc", sort=False)
    print(f"AUROC (OOD positive; {budget.caption()}):")
    print(table.round(3).to_string())
    if args.out:
        print(f"written to {args.out}")


if __name__ == "__main__":
    main()
