"""One state set per comparison: every member method scores the states the baseline agent collected (issue 66).

Each agent's own ID and OOD states differ in difficulty (Ant's best member-free detector reaches 0.80 on
Masksembles' states and 0.67 on MC Dropout's), so "method A detects better than method B" on their own states mixes
better uncertainty with easier states. The registered AUROC-order claim (docs/preregistration.md) reads instead the
baseline run's dataset of the same env and seed, scored by each member method's checkpoint:

    python -m paper_lib.pipeline.common_states ENV METHOD SEED      # the `common_score` stage of dvc.yaml

Raw states are the same for every agent; what each policy sees is its own normalizer's view of them
(`for_policy`). Scoring draws its ID split, its noise states and its cluster resamples from the run's seed alone, so
every method of one (env, seed) is scored on the same states with the same resamples: the differences between
methods are paired. The files go to results/<profile>/common_scores/<env>/<method>/seed<s>/ (metrics.csv,
replicates.npy, provenance.json naming the checkpoint and the baseline's dataset by digest).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import torch as th

from paper_lib.agents.training import stage_lock
from paper_lib.common.io import atomic_dir, write_json_atomic
from paper_lib.pipeline.config import RunConfig
from paper_lib.pipeline.layout import COMMON_STATES_OF as STATES_OF
from paper_lib.pipeline.layout import common_runs  # noqa: F401 (this module's readers use it with read_common)
from paper_lib.pipeline.run_cli import run_stage_main
from paper_lib.pipeline.run_results import (CHECKPOINT_INPUTS, PROVENANCE_FILE, _csv, _replicate_matrix,
                                             check_dataset_identity, load_run_dataset, provenance_record, read_replicate_matrix,
                                             read_score_csv, replicates_by_metric, run_identity)

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecNormalize

    from paper_lib.agents.checkpoints import Checkpoint
    from paper_lib.ood.datasets import StateDataset

FOLDER = "common_scores"
FILES = ("metrics.csv", "replicates.npy", PROVENANCE_FILE)


def common_scores_dir(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    return cfg.layout.common_scores_dir(env_id, method, seed)


def for_policy(dataset, vecnormalize):
    """`dataset` as a policy with normalizer `vecnormalize` (None: raw observations) sees it: the same raw states,
    `policy_obs` recomputed from them (the collecting agent's normalization is not this policy's)."""
    from dataclasses import replace

    if vecnormalize is None:
        return replace(dataset, policy_obs=None)
    vecnormalize.training = False
    return replace(dataset, policy_obs=vecnormalize.normalize_obs(dataset.states).astype(np.float32))


def saved_normalizer(path: Path | None):
    """A checkpoint's saved VecNormalize, its statistics frozen, without the env it wrapped: scoring reads committed
    files and builds no env (`make reproduce` runs this stage; load_checkpoint has checked the pickle)."""
    import pickle

    if path is None:
        return None
    with open(path, "rb") as f:
        normalizer = pickle.load(f)
    normalizer.training = False
    return normalizer


def common_provenance(cfg: RunConfig, env_id: str, method: str, seed: int) -> dict:
    """What the common-state scores are made from: this run's checkpoint and the baseline's dataset, by digest."""
    checkpoint = cfg.checkpoint_dir(env_id, method, seed)
    inputs = {"dataset": cfg.dataset_path(env_id, STATES_OF, seed),
              **{name: checkpoint / name for name in CHECKPOINT_INPUTS}}
    return {**provenance_record(run_identity(env_id, method, seed), inputs), "states_of": STATES_OF}


def score_common_files(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """Score run (env, method, seed)'s checkpoint on the baseline's dataset of that seed; write its files at once."""
    from paper_lib.agents.checkpoints import load_checkpoint

    if method == STATES_OF:
        raise ValueError(f"the {STATES_OF}'s own scores are on the common states already: score a member method")
    path = cfg.dataset_path(env_id, STATES_OF, seed)  # the common states of a seed are the baseline run's dataset
    data = load_run_dataset(path, env_id, STATES_OF, seed)
    check_dataset_identity(data.metadata, path, env_id, STATES_OF, seed)
    out = common_scores_dir(cfg, env_id, method, seed)
    th.set_num_threads(1)
    th.manual_seed(seed)  # as the `score` stage: MC members draw their masks from torch
    ckpt = load_checkpoint(cfg.checkpoint_dir(env_id, method, seed), env_id, method, seed)
    provenance = common_provenance(cfg, env_id, method, seed)
    vecnormalize = saved_normalizer(ckpt.vecnormalize_path)
    with stage_lock(out, "scoring the common states"):
        return _score_common_locked(cfg, env_id, method, seed, ckpt, data, vecnormalize, out, provenance)


def _score_common_locked(cfg: RunConfig, env_id: str, method: str, seed: int, ckpt: Checkpoint, data: StateDataset,
                         vecnormalize: VecNormalize | None, out: Path, provenance: dict) -> Path:
    """`score_common_files` once this process holds the common scores folder's lock."""
    from paper_lib.scoring.ood_scores import score_run

    run = score_run(ckpt, for_policy(data, vecnormalize), seed, cfg.n_bootstrap,
                    n_scoring_seeds=getattr(cfg, "n_scoring_seeds", 1), vecnormalize=vecnormalize)
    metrics = run.metrics.assign(states="common", states_of=STATES_OF, env=env_id, method=method, seed=seed)
    with atomic_dir(out) as tmp:
        (tmp / "metrics.csv").write_text(_csv(metrics))
        write_json_atomic(tmp / PROVENANCE_FILE, provenance)
        np.save(tmp / "replicates.npy", _replicate_matrix(run.metrics, run.replicates))
    return out


def read_common(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> tuple[pd.DataFrame, dict]:
    """(metrics, replicates keyed (env, method, seed, ood_set, measure)) of the common-state scores of `runs`; a
    folder whose provenance names other files than the run's checkpoint and the baseline's dataset now is refused."""
    frames, replicates = [], {}
    for run in runs:
        folder = common_scores_dir(cfg, *run)
        if not (folder / "metrics.csv").is_file():
            raise FileNotFoundError(f"{folder} has no common-state scores: run `dvc repro -s common_score@"
                                    f"{run[0]}-{run[1]}-{run[2]}` (`make reproduce` makes every stale one)")
        import json

        rescore = f"score it again (`python -m paper_lib.pipeline.common_states {run[0]} {run[1]} {run[2]}`)"
        if json.loads((folder / PROVENANCE_FILE).read_text()) != common_provenance(cfg, *run):
            raise ValueError(f"{folder} was scored from other files than {run[0]} {run[1]} seed {run[2]}'s checkpoint "
                             f"and the {STATES_OF}'s dataset hold now: {rescore}")
        metrics = read_score_csv(folder, "metrics.csv", run_identity(*run), rescore)
        matrix = read_replicate_matrix(folder, len(metrics), rescore)
        frames.append(metrics)
        for (ood_set, measure), row in replicates_by_metric(metrics, matrix).items():
            replicates[(*run, ood_set, measure)] = row
    return (pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()), replicates


def main(argv: list[str] | None = None) -> None:
    run_stage_main(argv, __doc__.splitlines()[0],
                   lambda cfg, env_id, method, seed, _params: score_common_files(cfg, env_id, method, seed))


if __name__ == "__main__":
    main()
