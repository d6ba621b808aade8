"""Per-run results that the tables and figures aggregate: reward episodes and OOD scores of one run.

    python -m paper_lib.pipeline.run_results evaluate HalfCheetah-v5 masksembles 0   # plays episodes: minutes per run
    python -m paper_lib.pipeline.run_results score HalfCheetah-v5 masksembles 0      # scores its dataset: seconds per run

Why per run: the work that grows with the number of runs (playing evaluation episodes, scoring
4000 states with every measure and detector, bootstrapping AUROC) is done once per run by a DVC
matrix stage and committed, so rebuilding every table and figure only reads small files, however
many runs a profile holds, and a run is redone only when its checkpoint, dataset or the code
that scores it changed.

Files (profile P, env E, method M, seed S):
    results/P/evaluations/E/M/seedS.csv       one row per evaluation episode
    results/P/scores/E/M/seedS/metrics.csv    AUROC, AUPR, FPR@95, ... per (OOD set, measure or detector)
                              roc.csv        ROC curve per (OOD set, measure), sampled on a fixed FPR grid
                              over_time.csv  the first ID states, then the first OOD states, scored per step
                              perturbation_ratios.csv  uncertainty on perturbed ID states / on ID states
                              replicates.npy  AUROC bootstrap replicates, row i for metrics.csv row i
                              source_coverage.csv  Atari only: did the ID rollouts reach the OOD source's
                                                   game states (paper_lib.ood.coverage), one row
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch as th

from paper_lib.agents.envs import is_atari
from paper_lib.common.io import atomic_dir, write_text_atomic
from paper_lib.pipeline.config import RunConfig, load_run_config

#: FPR values at which each ROC curve is kept (the TPR reachable at FPR <= x).
ROC_GRID = np.linspace(0.0, 1.0, 201)
SCORE_FILES = ("metrics.csv", "roc.csv", "over_time.csv", "perturbation_ratios.csv", "replicates.npy")
#: Atari runs add the check that the agent's ID rollouts never reached the OOD source's game states.
ATARI_SCORE_FILES = ("source_coverage.csv",)
OVER_TIME_MEASURES = ("value_std", "policy_std", "policy_js")
OVER_TIME_STATES = 1000  # ID states, then OOD states, kept per run for the over-time figures


def evaluation_path(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    return cfg.results / "evaluations" / env_id / method / f"seed{seed}.csv"


def scores_dir(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    return cfg.results / "scores" / env_id / method / f"seed{seed}"


def score_files(env_id: str) -> tuple[str, ...]:
    """The files a run's scores folder holds once scored: Atari runs have the source coverage check too."""
    return SCORE_FILES + (ATARI_SCORE_FILES if is_atari(env_id) else ())


def _csv(df: pd.DataFrame) -> str:
    return df.to_csv(index=False, lineterminator="\n")


# ----------------------------------------------------------------------------- stages


def evaluate_run(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """Play the profile's evaluation episodes with one checkpoint (paper Table 1) and save one row per episode."""
    from paper_lib.agents.checkpoints import load_checkpoint
    from paper_lib.scoring.rewards import evaluate_rewards

    th.set_num_threads(1)
    th.manual_seed(10_000 + seed)  # sampled actions and MC members draw from torch: same seed, same episodes
    ckpt = load_checkpoint(cfg.checkpoint_dir(env_id, method, seed), env_id, method, seed)
    episodes = evaluate_rewards(ckpt, cfg.eval_episodes, seed=10_000 + seed)
    return write_text_atomic(evaluation_path(cfg, env_id, method, seed),
                             _csv(episodes.assign(env=env_id, method=method, seed=seed)))


def roc_on_grid(roc: pd.DataFrame, grid: np.ndarray = ROC_GRID) -> pd.DataFrame:
    """Each ROC curve (columns fpr, tpr, measure, ood_set) as the best TPR reachable at FPR <= x, x on `grid`.

    Exact at the grid points (sklearn's points are sorted with non-decreasing fpr and tpr), and a
    few kB per curve instead of one row per distinct score.
    """
    parts = []
    for (ood_set, measure), curve in roc.groupby(["ood_set", "measure"], sort=False):
        fpr, tpr = curve["fpr"].to_numpy(), curve["tpr"].to_numpy()
        last = np.searchsorted(fpr, grid, side="right") - 1
        parts.append(pd.DataFrame({"ood_set": ood_set, "measure": measure, "fpr": grid,
                                   "tpr": np.maximum.accumulate(tpr)[np.maximum(last, 0)]}))
    return pd.concat(parts, ignore_index=True)


def first_episodes(model, dataset, max_states: int = OVER_TIME_STATES) -> pd.DataFrame:
    """The dataset's first `max_states` ID states, then its first `max_states` OOD states, in time order, scored per step.

    States are stored episode by episode in the order they were played, so the first ones of each
    label are whole episodes (ID) or configurations (OOD) one after the other, as the paper's
    over-time figures concatenate them.
    """
    from paper_lib.ood.collect import score_dataset

    parts = []
    for label, phase in ((0, "id"), (1, "ood")):
        sub = dataset.subset(dataset.labels == label)
        sub = sub.subset(np.arange(len(sub)) < max_states)
        scored = score_dataset(model, sub)
        keep = [m for m in OVER_TIME_MEASURES if m in scored]
        parts.append(scored[["episode", "step", *keep]].assign(phase=phase))
    out = pd.concat(parts, ignore_index=True)
    return out.rename(columns={"step": "episode_step"}).assign(step=np.arange(len(out)))


def collection_protocol(dataset) -> str:
    """The name of the protocol the dataset's OOD states were collected with ("main", "appendix"), from its metadata.

    Captions say how the scored states were collected from this, not from params.yaml, which
    may have changed since the datasets were committed.
    """
    parts = dataset.metadata.get("parts") or [dataset.metadata]
    names = [(p.get("protocol") or {}).get("name") for p in parts if p.get("kind", "").endswith("ood")]
    return next((str(n) for n in names if n), "unknown")


def collection_actions(dataset) -> str:
    """'sampled actions, vote inference' and the like: how the agent acted while its states were collected."""
    parts = dataset.metadata.get("parts") or [dataset.metadata]  # Atari-HEAD OOD states record no action mode
    mode = dataset.metadata.get("action_mode") or next((p["action_mode"] for p in parts if p.get("action_mode")), {})
    if not mode:
        return "unknown"
    actions = "deterministic" if mode.get("deterministic") else "sampled"
    return f"{actions} actions, {mode.get('inference')} inference"


def _identity_error(path: Path, found: dict[str, Any], env_id: str, method: str, seed: int) -> ValueError:
    wanted = f"{env_id} {method} seed {seed}"
    got = " ".join(str(found.get(key)) for key in ("env", "method")) + f" seed {found.get('seed')}"
    return ValueError(f"{path} belongs to {got}, not to {wanted} whose path it sits at: a file of another run is never "
                      f"read as this one's; put back this run's file (`make recollect` collects it again)")


def check_dataset_identity(metadata: dict[str, Any], path: Path, env_id: str, method: str, seed: int) -> None:
    """The dataset at a run's path must name that run in its metadata (the model that collected it)."""
    model = metadata.get("model") or {}
    found = {"env": model.get("env_id", metadata.get("env_id")), "method": model.get("method"), "seed": model.get("seed")}
    if (found["env"], found["method"], found["seed"]) != (env_id, method, seed):
        raise _identity_error(path, found, env_id, method, seed)


def check_evaluation_identity(episodes: pd.DataFrame, path: Path, env_id: str, method: str, seed: int) -> None:
    """Every episode of the evaluation file at a run's path must be that run's (its env, method, seed columns)."""
    for key, value in (("env", env_id), ("method", method), ("seed", seed)):
        values = set(episodes[key]) if key in episodes else {None}
        if values != {value}:
            found = {k: ", ".join(map(str, sorted(set(episodes[k]), key=str))) if k in episodes else None
                     for k in ("env", "method", "seed")}
            raise _identity_error(path, found, env_id, method, seed)


def score_run_files(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """Score one run's ID/OOD dataset with every measure and detector; write its four result files at once."""
    from paper_lib.agents.checkpoints import load_checkpoint
    from paper_lib.ood.datasets import StateDataset
    from paper_lib.scoring.ood_scores import score_run
    from paper_lib.scoring.perturbation_bars import perturbation_ratios

    th.set_num_threads(1)
    th.manual_seed(seed)  # MC Dropout / DropConnect members draw their masks from torch
    ckpt = load_checkpoint(cfg.checkpoint_dir(env_id, method, seed), env_id, method, seed)
    path = cfg.dataset_path(env_id, method, seed)
    if not path.is_file():
        raise FileNotFoundError(f"dataset {path} is missing; collect it with `dvc repro -s collect@{env_id}-{method}-{seed}` "
                                "(`make recollect` collects every run's)")
    data = StateDataset.load(path)
    check_dataset_identity(data.metadata, path, env_id, method, seed)
    tag = {"env": env_id, "method": method, "seed": seed}
    run = score_run(ckpt, data, seed, cfg.n_bootstrap, n_scoring_seeds=getattr(cfg, "n_scoring_seeds", 1))
    files = {"metrics.csv": run.metrics.assign(protocol=collection_protocol(data), actions=collection_actions(data), **tag),
             "roc.csv": roc_on_grid(run.roc).assign(**tag)}
    if method == "baseline":  # no members: no member measure to follow over time or to compare under perturbation
        files["over_time.csv"] = pd.DataFrame(columns=["step", "episode_step", "phase", "episode", *tag])
        files["perturbation_ratios.csv"] = pd.DataFrame(columns=["perturbation", "measure", "ratio", *tag])
    else:
        files["over_time.csv"] = first_episodes(ckpt.model, data).assign(**tag)
        files["perturbation_ratios.csv"] = perturbation_ratios(ckpt, data, np.random.default_rng(seed)).assign(**tag)
    if is_atari(env_id):
        from paper_lib.ood.coverage import source_coverage

        files["source_coverage.csv"] = source_coverage(data).assign(**tag)
    out = scores_dir(cfg, env_id, method, seed)
    with atomic_dir(out) as tmp:
        for name, df in files.items():
            (tmp / name).write_text(_csv(df))
        # AUROC bootstrap replicates, one row per metrics.csv row, for intervals that pool seeds (float32, NaN-padded;
        # .npy has no timestamp, so the same replicates give the same bytes).
        np.save(tmp / "replicates.npy", _replicate_matrix(run.metrics, run.replicates))
    return out


def _replicate_matrix(metrics: pd.DataFrame, replicates: pd.DataFrame) -> np.ndarray:
    """(rows of `metrics`, max replicates) float32 matrix of each (ood_set, measure)'s replicates."""
    groups = {key: g["auroc"].to_numpy() for key, g in replicates.groupby(["ood_set", "measure"], sort=False)}
    rows = [groups.get((o, m), np.array([])) for o, m in zip(metrics["ood_set"], metrics["measure"])]
    out = np.full((len(rows), max([len(r) for r in rows] + [1])), np.nan, dtype=np.float32)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


# ----------------------------------------------------------------------------- readers


def read_evaluations(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> pd.DataFrame:
    """Every evaluation episode of `runs` in one frame (env, method, seed, inference, deterministic, ...); a file at
    a run's path that holds another run's episodes is refused."""
    frames = []
    for run in runs:
        path = evaluation_path(cfg, *run)
        episodes = pd.read_csv(path)
        check_evaluation_identity(episodes, path, *run)
        frames.append(episodes)
    return pd.concat(frames, ignore_index=True)


def read_replicates(cfg: RunConfig, run: tuple[str, str, int]) -> dict[tuple[str, str], np.ndarray]:
    """One run's AUROC bootstrap replicates per (ood_set, measure), e.g. for `metrics.seed_cluster_ci` over seeds."""
    folder = scores_dir(cfg, *run)
    metrics, matrix = pd.read_csv(folder / "metrics.csv"), np.load(folder / "replicates.npy")
    return {(o, m): row[~np.isnan(row)].astype(float) for o, m, row in zip(metrics["ood_set"], metrics["measure"], matrix)}


def read_all_replicates(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> dict[tuple[str, str, int, str, str], np.ndarray]:
    """Every run's AUROC bootstrap replicates, keyed (env, method, seed, ood_set, measure)."""
    return {(*run, ood_set, measure): reps for run in runs for (ood_set, measure), reps in read_replicates(cfg, run).items()}


def read_scores(cfg: RunConfig, runs: list[tuple[str, str, int]], name: str) -> pd.DataFrame:
    """One of the score files (`metrics`, `roc`, `over_time`, `perturbation_ratios`) of `runs`, concatenated."""
    if f"{name}.csv" not in SCORE_FILES:
        raise ValueError(f"unknown score file {name!r}; use one of {[f[:-4] for f in SCORE_FILES]}")
    frames = [pd.read_csv(scores_dir(cfg, *run) / f"{name}.csv") for run in runs]
    frames = [f for f in frames if not f.empty] or frames[:1]
    return pd.concat(frames, ignore_index=True)


def read_source_coverage(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> pd.DataFrame:
    """The source coverage rows (one per run) of the Atari runs among `runs`, for a table; empty if none."""
    from paper_lib.ood.coverage import COVERAGE_COLUMNS

    paths = [scores_dir(cfg, *run) / ATARI_SCORE_FILES[0] for run in runs if is_atari(run[0])]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"no source coverage file {missing[0]} ({len(missing)} missing): score those runs "
                                "again (`python -m paper_lib.pipeline.run_results score <env> <method> <seed>`).")
    frames = [pd.read_csv(p) for p in paths]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=[*COVERAGE_COLUMNS, "env",
                                                                                     "method", "seed"])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Per-run results: reward episodes (evaluate) and OOD scores (score).")
    parser.add_argument("stage", choices=("evaluate", "score"))
    parser.add_argument("env_id")
    parser.add_argument("method")
    parser.add_argument("seed", type=int)
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args(argv)
    try:
        cfg = load_run_config(args.params)
        if (args.env_id, args.method, args.seed) not in cfg.runs():
            raise ValueError(f"{args.env_id} {args.method} seed {args.seed} is not a run of profile {cfg.profile!r} "
                             f"(envs {cfg.envs}, methods {cfg.methods}, seeds {cfg.seeds})")
        stage = evaluate_run if args.stage == "evaluate" else score_run_files
        print(stage(cfg, args.env_id, args.method, args.seed))
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")


if __name__ == "__main__":
    main()
