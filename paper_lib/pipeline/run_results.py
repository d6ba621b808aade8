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
                              provenance.json  what the scores were made from: the run, and the SHA-256 of its
                                               dataset and checkpoint files (readers refuse scores whose
                                               inputs changed since; `provenance` writes it for older scores)
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import torch as th

from paper_lib.agents.envs import is_atari
from paper_lib.agents.training import stage_lock
from paper_lib.common.io import (DestinationError, atomic_dir, check_replaceable_dir, write_json_atomic,
                                 write_text_atomic)
from paper_lib.common.provenance import file_digest
from paper_lib.pipeline.config import RunConfig, load_run_config
from paper_lib.pipeline.layout import Layout, Run, combination_name, stage_suffix

if TYPE_CHECKING:
    from paper_lib.agents.checkpoints import Checkpoint
    from paper_lib.ood.datasets import StateDataset

#: FPR values at which each ROC curve is kept (the TPR reachable at FPR <= x).
ROC_GRID = np.linspace(0.0, 1.0, 201)
SCORE_FILES = ("metrics.csv", "roc.csv", "over_time.csv", "perturbation_ratios.csv", "replicates.npy")
#: Atari runs add the check that the agent's ID rollouts never reached the OOD source's game states.
ATARI_SCORE_FILES = ("source_coverage.csv",)
OVER_TIME_MEASURES = ("value_std", "policy_std", "policy_js")
OVER_TIME_STATES = 1000  # ID states, then OOD states, kept per run for the over-time figures
#: What a scores folder was made from (`score_provenance`): the run, and the SHA-256 of its dataset and checkpoint.
PROVENANCE_FILE = "provenance.json"
PROVENANCE_FORMAT = "paper_lib.ScoreProvenance/1"


def evaluation_path(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """One run's reward episodes; `cfg` needs only its `results` folder (a tree of paper_lib.pipeline.layout)."""
    return Layout(cfg.results).evaluation_path(env_id, method, seed)


def scores_dir(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """One run's scores folder; `cfg` needs only its `results` folder."""
    return Layout(cfg.results).scores_dir(env_id, method, seed)


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
    path = evaluation_path(cfg, env_id, method, seed)
    with stage_lock(path, "evaluating"):
        episodes = evaluate_rewards(ckpt, cfg.eval_episodes, seed=10_000 + seed)
        return write_text_atomic(path, _csv(episodes.assign(env=env_id, method=method, seed=seed)))


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
    from paper_lib.scoring.ood_scores import score_dataset

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


#: The keys of a record that name what was scored: a run (env, method, seed), or an ensemble assembled from member
#: checkpoints (env, method, members: paper_lib.experiments.ensembles).
IDENTITY_KEYS = ("env", "method", "seed", "members")


def run_identity(env_id: str, method: str, seed: int) -> dict[str, Any]:
    return {"env": env_id, "method": method, "seed": seed}


def describe_identity(identity: dict[str, Any]) -> str:
    """'HalfCheetah-v5 masksembles seed 0', or 'Walker2d-v5 independent_ensemble members-0-1-2-3'."""
    members = identity.get("members")
    tail = f"seed {identity.get('seed')}" if members is None else (
        combination_name(tuple(members)) if isinstance(members, list) else str(members))
    return f"{identity.get('env')} {identity.get('method')} {tail}"


#: How to get a run's own dataset or evaluation back, the default fix of `identity_error`.
RECOLLECT = "put back this run's file (`make recollect` collects it again)"


def identity_error(path: Path, found: dict[str, Any], wanted: dict[str, Any], fix: str = RECOLLECT) -> ValueError:
    return ValueError(f"{path} belongs to {describe_identity(found)}, not to {describe_identity(wanted)} whose path it "
                      f"sits at: a file of another run is never read as this one's; {fix}")


def check_dataset_identity(metadata: dict[str, Any], path: Path, env_id: str, method: str, seed: int) -> None:
    """The dataset at a run's path must name that run in its metadata (the model that collected it)."""
    model = metadata.get("model") or {}
    found = {"env": model.get("env_id", metadata.get("env_id")), "method": model.get("method"), "seed": model.get("seed")}
    if (found["env"], found["method"], found["seed"]) != (env_id, method, seed):
        raise identity_error(path, found, run_identity(env_id, method, seed))


def check_evaluation_identity(episodes: pd.DataFrame, path: Path, env_id: str, method: str, seed: int,
                              fix: str = RECOLLECT) -> None:
    """Every row of the file at a run's path (evaluation episodes, scores) must be that run's (its env, method, seed
    columns). A file with a header but no row (a baseline's over_time.csv) names no run and passes."""
    if episodes.empty and all(key in episodes for key in ("env", "method", "seed")):
        return
    for key, value in (("env", env_id), ("method", method), ("seed", seed)):
        values = set(episodes[key]) if key in episodes else {None}
        if values != {value}:
            found = {k: ", ".join(map(str, sorted(set(episodes[k]), key=str))) if k in episodes else None
                     for k in ("env", "method", "seed")}
            raise identity_error(path, found, run_identity(env_id, method, seed), fix)


# ----------------------------------------------------------------------------- provenance: scores <- their inputs

#: The files of a run that its scores are made from, by the name `provenance.json` records each under; the
#: checkpoint's normalizer only where the checkpoint has one.
CHECKPOINT_INPUTS = ("model.zip", "vecnormalize.pkl")
_DIGESTS: dict[tuple[int, int, int, int], str] = {}  # (device, inode, size, mtime) -> SHA-256: tables read a run often


def _digest(path: Path) -> str:
    """`file_digest`, computed once per version of a file (the stat key changes when the file does)."""
    st = os.stat(path)
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    if key not in _DIGESTS:
        _DIGESTS[key] = file_digest(path)
    return _DIGESTS[key]


def provenance_inputs(cfg: RunConfig, env_id: str, method: str, seed: int) -> dict[str, Path]:
    """Where the files a run's scores are made from sit now: its dataset, its checkpoint's model.zip and normalizer."""
    checkpoint = cfg.checkpoint_dir(env_id, method, seed)
    return {"dataset": cfg.dataset_path(env_id, method, seed),
            **{name: checkpoint / name for name in CHECKPOINT_INPUTS}}


def _anchor(name: str) -> str:
    """The input whose presence says whether `name` can be compared: a checkpoint's normalizer goes with its model.zip
    (`seed0/vecnormalize.pkl` with `seed0/model.zip`, for an ensemble's members); every other input is its own."""
    folder, sep, file = name.rpartition("/")
    return f"{folder}{sep}{CHECKPOINT_INPUTS[0]}" if file == CHECKPOINT_INPUTS[1] else name


def provenance_record(identity: dict[str, Any], inputs: dict[str, Path]) -> dict[str, Any]:
    """The `provenance.json` of scores made from `inputs` (name -> file): what was scored (`identity`, IDENTITY_KEYS)
    and the SHA-256 of each input present, by name. No time and no path, so scoring the same files again gives the
    same bytes. A missing dataset or model.zip (a normalizer is optional) is one error naming it."""
    for name, path in inputs.items():
        if _anchor(name) == name and not path.is_file():
            raise FileNotFoundError(f"{path} is missing: the scores of {describe_identity(identity)} are made from it; "
                                    "put it back (`make recollect` collects a dataset again)")
    digests = {name: _digest(path) for name, path in inputs.items() if path.is_file()}
    return {"format": PROVENANCE_FORMAT, **identity, "sha256": digests}


def score_provenance(cfg: RunConfig, env_id: str, method: str, seed: int) -> dict[str, Any]:
    """What the run's scores are made from, as `provenance.json` holds it (`provenance_record` of the run)."""
    return provenance_record(run_identity(env_id, method, seed), provenance_inputs(cfg, env_id, method, seed))


def _run_fixes(env_id: str, method: str, seed: int) -> tuple[str, str]:
    """(how to score the run again, the command that records existing scores) for a main-matrix run."""
    return (f"score the run again (`python -m paper_lib.pipeline.run_results score {env_id} {method} {seed}`)",
            f"python -m paper_lib.pipeline.run_results provenance {env_id} {method} {seed}")


def _read_provenance(path: Path, rescore: str, backfill: str) -> dict[str, Any]:
    try:
        recorded = json.loads(path.read_text())
        if not (isinstance(recorded, dict) and recorded.get("format") == PROVENANCE_FORMAT
                and isinstance(recorded.get("sha256"), dict)):
            raise ValueError(f"not a {PROVENANCE_FORMAT} record")
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ValueError(f"{path} is not a readable provenance record ({err}); {rescore}, or write the record from "
                         f"its current files (`{backfill}`)") from None
    return recorded


def check_provenance(folder: Path, identity: dict[str, Any], inputs: dict[str, Path], rescore: str, backfill: str,
                     required: bool = False) -> None:
    """Scores in `folder` must have been made from `identity`'s current `inputs` (what `provenance_record` records).

    The record must name `identity`, and each input present now must have the SHA-256 recorded; an input missing here
    (a checkout without datasets) cannot be compared and is passed over (a checkpoint's files go with its model.zip).
    A folder without its record is passed over too, unless `required`: then it is refused, naming `backfill`, the
    command that records existing scores after checking them. `rescore` says how to make the scores again.
    """
    path = folder / PROVENANCE_FILE
    if not path.is_file():
        if not required:
            return
        raise ValueError(f"the scores {folder} have no {PROVENANCE_FILE}: what they were made from is not recorded, "
                         f"so they are not read as {describe_identity(identity)}'s; record it from the current files, "
                         f"which the command checks first (`{backfill}`), or {rescore}")
    recorded = _read_provenance(path, rescore, backfill)
    if any(recorded.get(key) != identity.get(key) for key in IDENTITY_KEYS):
        raise identity_error(path, recorded, identity, rescore)
    for name, file in inputs.items():
        if not inputs[_anchor(name)].is_file():
            continue
        want, now = recorded["sha256"].get(name), _digest(file) if file.is_file() else None
        if want != now:
            raise ValueError(f"the scores {folder} were made from {name} SHA-256 {_short(want)}, but {file} is now "
                             f"{_short(now)}: they are stale or another run's; {rescore}")


def check_score_provenance(cfg: RunConfig, env_id: str, method: str, seed: int, *, required: bool = False,
                           rescore: str | None = None, backfill: str | None = None) -> None:
    """Scores at a run's path must have been made from that run's current dataset and checkpoint (`check_provenance`).

    Scores made before the record existed have none: passed over here, refused where `required` (the ensembles'
    readers), naming `backfill` (default: this module's `provenance` command). `rescore` defaults to the score stage.
    """
    folder = scores_dir(cfg, env_id, method, seed)
    if not required and not (folder / PROVENANCE_FILE).is_file():
        return  # passed over (see check_provenance) before the inputs are even looked up
    fixes = _run_fixes(env_id, method, seed)
    check_provenance(folder, run_identity(env_id, method, seed),
                     provenance_inputs(cfg, env_id, method, seed), rescore or fixes[0], backfill or fixes[1], required)


def _short(digest: str | None) -> str:
    return "none (no such file)" if digest is None else f"{digest[:12]}..."


def check_scores_destination(folder: Path, env_id: str, names: tuple[str, ...] | None = None) -> Path:
    """The score stage replaces its folder whole: refuse a file or a link there, or a folder holding files but none
    of a scores folder's (`names`; default: a run's, `score_files` and provenance.json), before any scoring (the swap
    would delete them)."""
    check_replaceable_dir(folder, "scores folder")
    ours = names or (*score_files(env_id), PROVENANCE_FILE)
    if folder.is_dir() and any(folder.iterdir()) and not any((folder / name).is_file() for name in ours):
        raise DestinationError(f"scores folder {folder} holds files but none of a scores folder's ({', '.join(ours)}), "
                               "and scoring would replace it whole; move those files away (they were left as they are)")
    return folder


def provenance_to_write(folder: Path, record: dict[str, Any], inputs: dict[str, Path], rescore: str,
                        backfill: str) -> dict[str, Any] | None:
    """A backfill's last check: `record` (from the current `inputs`) if `folder` has no record yet, None if it holds
    the same one; a record there naming other inputs is refused, naming the one that differs (never overwritten with
    the current ones: that would bless stale scores)."""
    path = folder / PROVENANCE_FILE
    if not path.is_file():
        return record
    if _read_provenance(path, rescore, backfill) == record:
        return None  # already recorded: left untouched
    identity = {key: record[key] for key in IDENTITY_KEYS if key in record}
    check_provenance(folder, identity, inputs, rescore, backfill)  # names the input that differs
    raise ValueError(f"{path} already records other inputs than {describe_identity(identity)}'s current files; "
                     f"{rescore} instead (it was left as it is)")


def provenance_to_record(cfg: RunConfig, env_id: str, method: str, seed: int, rescore: str | None = None,
                         backfill: str | None = None) -> dict[str, Any] | None:
    """The record `record_provenance` writes for one run (None: already there), after every check on the run;
    `rescore` and `backfill` as in `check_score_provenance`."""
    fixes = _run_fixes(env_id, method, seed)
    rescore, backfill = rescore or fixes[0], backfill or fixes[1]
    folder = scores_dir(cfg, env_id, method, seed)
    if not (folder / "metrics.csv").is_file():
        raise FileNotFoundError(f"{folder} holds no scores (no metrics.csv): {rescore}")
    read_score_csv(folder, "metrics.csv", run_identity(env_id, method, seed), rescore)  # whole, and this run's
    provenance = score_provenance(cfg, env_id, method, seed)
    inputs = provenance_inputs(cfg, env_id, method, seed)
    with np.load(inputs["dataset"], allow_pickle=False) as data:
        check_dataset_identity(json.loads(str(data["metadata"])), inputs["dataset"], env_id, method, seed)
    return provenance_to_write(folder, provenance, inputs, rescore, backfill)


def record_provenance(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> list[Path]:
    """Write `provenance.json` into scores folders made before it was recorded, from each run's current files.

    For committed scores whose dataset and checkpoint have not changed since they were scored (what `make verify`
    shows); nothing is rescored. Every run is checked before any file is written: a folder of another run's scores
    (metrics.csv names another run), a dataset of another run, a missing input, or a record that already names other
    inputs is one error, and nothing is written. Returns the records written (runs already recorded are left as
    they are).
    """
    records = {run: provenance_to_record(cfg, *run) for run in runs}
    return [write_json_atomic(scores_dir(cfg, *run) / PROVENANCE_FILE, record)
            for run, record in records.items() if record is not None]


def load_run_dataset(path: Path, env_id: str, method: str, seed: int) -> StateDataset:
    """A run's collected states; missing or damaged, the error names both ways back: the committed copy, or the
    stage that collects it (a dataset is simulation: no rebuild writes it)."""
    from paper_lib.ood.datasets import StateDataset

    remedy = (f"restore the committed copy (`git checkout -- {path}`) or collect it again (`dvc repro -s "
              f"collect@{stage_suffix(env_id, method, seed)}`; `make recollect` collects every run's)")
    if not path.is_file():
        raise FileNotFoundError(f"dataset {path} is missing; {remedy}")
    return StateDataset.load(path, remedy=remedy)


def score_run_files(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """Score one run's ID/OOD dataset with every measure and detector; write its result files and their provenance
    at once."""
    from paper_lib.agents.checkpoints import load_checkpoint

    out = check_scores_destination(scores_dir(cfg, env_id, method, seed), env_id)  # before any work
    th.set_num_threads(1)
    th.manual_seed(seed)  # MC Dropout / DropConnect members draw their masks from torch
    ckpt = load_checkpoint(cfg.checkpoint_dir(env_id, method, seed), env_id, method, seed)
    path = cfg.dataset_path(env_id, method, seed)
    data = load_run_dataset(path, env_id, method, seed)
    check_dataset_identity(data.metadata, path, env_id, method, seed)
    with stage_lock(out, "scoring"):
        return _score_locked(cfg, env_id, method, seed, ckpt, data, out)


def _score_locked(cfg: RunConfig, env_id: str, method: str, seed: int, ckpt: Checkpoint, data: StateDataset,
                  out: Path) -> Path:
    """`score_run_files` once this process holds the scores folder's lock; the provenance is taken now, from the
    files as they are when scoring starts."""
    from paper_lib.scoring.ood_scores import score_run
    from paper_lib.scoring.perturbation_bars import perturbation_ratios

    provenance = score_provenance(cfg, env_id, method, seed)
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
    with atomic_dir(out) as tmp:
        for name, df in files.items():
            (tmp / name).write_text(_csv(df))
        write_json_atomic(tmp / PROVENANCE_FILE, provenance)
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
        episodes = read_evaluation_file(path, *run, n_episodes=getattr(cfg, "eval_episodes", None))
        check_evaluation_identity(episodes, path, *run)
        frames.append(episodes)
    return pd.concat(frames, ignore_index=True)


#: The columns `evaluate_run` writes that every episode fills (`member` is empty for combined inference).
EVALUATION_COLUMNS = ("inference", "deterministic", "member", "reward", "length", "env", "method", "seed")


def read_evaluation_file(path: Path, env_id: str, method: str, seed: int, n_episodes: int | None = None) -> pd.DataFrame:
    """A run's evaluation episodes, refused with one error naming the file where it is not whole.

    A file cut off (a copy or a write interrupted) must not become a reward table of fewer episodes, or an error
    deep in the statistics: `evaluate_run` ends every file with a line end, writes every column of every episode,
    and plays as many episodes in each (action mode, inference) as in every other, each action mode of the env:
    `n_episodes` (the profile's eval_episodes) where given.
    """
    from paper_lib.scoring.rewards import action_modes

    def incomplete(what: str) -> ValueError:
        return ValueError(f"{path} is incomplete (cut off?): {what}; evaluate the run again "
                          f"(`python -m paper_lib.pipeline.run_results evaluate {env_id} {method} {seed}`)")

    if not path.is_file():
        raise FileNotFoundError(f"no evaluation file {path}: evaluate the run "
                                f"(`python -m paper_lib.pipeline.run_results evaluate {env_id} {method} {seed}`)")
    episodes = read_whole_csv(path, incomplete)
    missing = [c for c in EVALUATION_COLUMNS if c not in episodes]
    if missing:
        raise incomplete(f"it lacks the column(s) {missing}")
    if episodes.empty:
        raise incomplete("it holds a header but no episode")
    empty = [c for c in EVALUATION_COLUMNS if c != "member" and episodes[c].isna().any()]
    if empty:
        raise incomplete(f"some episodes have no {', '.join(empty)}")
    counts = episodes.groupby(["deterministic", "inference"], sort=False).size()  # in the order played
    expected = {(d, i) for d in action_modes(env_id) for i in set(episodes["inference"])}
    if set(counts.index) != expected or counts.nunique() != 1:
        found = ", ".join(f"{n} {i} {'deterministic' if d else 'sampled'}" for (d, i), n in counts.items())
        raise incomplete(f"each action mode and inference needs as many episodes as the others, got {found}")
    if n_episodes is not None and counts.iloc[0] != n_episodes:  # e.g. every episode twice: a file appended to itself
        raise ValueError(f"{path} holds {counts.iloc[0]} episodes per action mode and inference, but the profile plays "
                         f"{n_episodes} (eval_episodes): episodes were added twice or the file is of another "
                         f"profile; evaluate the run again (`python -m paper_lib.pipeline.run_results evaluate {env_id} "
                         f"{method} {seed}`)")
    return episodes


def read_whole_csv(path: Path, incomplete: Callable[[str], Exception]) -> pd.DataFrame:
    """A CSV the pipeline wrote, or `incomplete(what)` raised: every writer ends its files with a line end, so a file
    without one was cut off mid-row (pandas would read the rows before the cut without a word)."""
    raw = path.read_bytes()
    if not raw.endswith(b"\n"):
        raise incomplete("it is empty" if not raw else "its last line ends mid-row")
    try:
        return pd.read_csv(path)
    except (ValueError, UnicodeDecodeError) as err:  # pandas' parser errors are ValueErrors
        raise incomplete(f"it is not a readable CSV ({type(err).__name__}: {' '.join(str(err).split())})") from None


def read_score_csv(folder: Path, name: str, identity: dict[str, Any], rescore: str) -> pd.DataFrame:
    """One score file, whole and of the run whose folder holds it (its env, method, seed columns), or one error naming
    the file and `rescore`: a file cut off or copied from another run is never read as this run's."""
    path = folder / name

    def incomplete(what: str) -> ValueError:
        return ValueError(f"{path} is incomplete (cut off?): {what}; {rescore}")

    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: the scores of {describe_identity(identity)} are not whole; "
                                f"{rescore}")
    frame = read_whole_csv(path, incomplete)
    check_evaluation_identity(frame, path, identity["env"], identity["method"], identity["seed"], rescore)
    if name == "roc.csv" and len(frame):  # the ROC of every (ood_set, measure) on the same grid: a cut drops points
        sizes = frame.groupby(["ood_set", "measure"], sort=False).size()
        if set(sizes) != {len(ROC_GRID)}:
            raise incomplete(f"each ROC needs {len(ROC_GRID)} points, got {sorted(set(sizes))}")
    return frame


def read_replicate_matrix(folder: Path, rows: int, rescore: str, name: str = "replicates.npy") -> np.ndarray:
    """replicates.npy (or `name`), one row per row of the metrics beside it (`rows`), or one error naming it and
    `rescore`."""
    path = folder / name
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: the scores in {folder} are not whole; {rescore}")
    try:
        matrix = np.load(path, allow_pickle=False)
    except (ValueError, EOFError, OSError) as err:  # a cut .npy: its header promises more bytes than follow
        raise ValueError(f"{path} is incomplete (cut off?): it is not a readable .npy ({type(err).__name__}: "
                         f"{err}); {rescore}") from None
    if matrix.ndim != 2 or len(matrix) != rows:
        raise ValueError(f"{path} holds {len(matrix) if matrix.ndim else 0} rows but the "
                         f"{name.replace('replicates.npy', 'metrics.csv')} beside it has "
                         f"{rows} (one row of replicates per metric): one of them is cut off or of another scoring; "
                         f"{rescore}")
    return matrix


def read_run_metrics(cfg: RunConfig, run: tuple[str, str, int]) -> tuple[pd.DataFrame, np.ndarray]:
    """(metrics.csv, replicates.npy) of one run: whole, of this run, row for row, from its current files."""
    check_score_provenance(cfg, *run, required=True)
    folder, rescore = scores_dir(cfg, *run), _run_fixes(*run)[0]
    metrics = read_score_csv(folder, "metrics.csv", run_identity(*run), rescore)
    return metrics, read_replicate_matrix(folder, len(metrics), rescore)


def replicates_by_metric(metrics: pd.DataFrame, matrix: np.ndarray) -> dict[tuple[str, str], np.ndarray]:
    """Each (ood_set, measure)'s replicates: its row of `matrix` without the NaN padding."""
    return {(o, m): row[~np.isnan(row)].astype(float) for o, m, row in zip(metrics["ood_set"], metrics["measure"], matrix)}


def read_peer_scores(runs: list[Run], folder_of: Callable[[Run], Path],
                     inputs_of: Callable[[Run], dict[str, Path]], rerun_of: Callable[[Run], str],
                     metrics_name: str = "metrics.csv", replicates_name: str = "replicates.npy",
                     ) -> tuple[pd.DataFrame, dict[tuple[str, str, int, str, str], np.ndarray]]:
    """(metrics, replicates keyed (env, method, seed, ood_set, measure)) of the runs among `runs` whose folder holds
    `metrics_name`, as a stage that scores Table 2's states beside the `score` stage writes them (the sequence
    detectors, PEDM). A run without the file is left out (a table says 'not scored'); files made from other inputs
    than the run's current ones, cut off, or of another run are one error naming the stage to run again."""
    frames, replicates = [], {}
    for run in runs:
        folder = folder_of(run)
        if not (folder / metrics_name).is_file():
            continue
        identity, rerun = run_identity(*run), rerun_of(run)
        check_provenance(folder, identity, inputs_of(run), rerun, rerun, required=True)
        metrics = read_score_csv(folder, metrics_name, identity, rerun)
        matrix = read_replicate_matrix(folder, len(metrics), rerun, name=replicates_name)
        frames.append(metrics)
        replicates |= {(*run, ood_set, measure): reps
                       for (ood_set, measure), reps in replicates_by_metric(metrics, matrix).items()}
    empty = pd.DataFrame(columns=["env", "method", "seed", "ood_set", "measure", "auroc"])
    return (pd.concat(frames, ignore_index=True) if frames else empty), replicates


def read_replicates(cfg: RunConfig, run: tuple[str, str, int]) -> dict[tuple[str, str], np.ndarray]:
    """One run's AUROC bootstrap replicates per (ood_set, measure), e.g. for `statistics.seed_cluster_ci` over seeds."""
    return replicates_by_metric(*read_run_metrics(cfg, run))


def read_all_replicates(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> dict[tuple[str, str, int, str, str], np.ndarray]:
    """Every run's AUROC bootstrap replicates, keyed (env, method, seed, ood_set, measure)."""
    return {(*run, ood_set, measure): reps for run in runs for (ood_set, measure), reps in read_replicates(cfg, run).items()}


def read_scores(cfg: RunConfig, runs: list[tuple[str, str, int]], name: str) -> pd.DataFrame:
    """One of the score files (`metrics`, `roc`, `over_time`, `perturbation_ratios`) of `runs`, concatenated. Scores
    without a provenance record, or whose record names other inputs than the run's current files, are refused
    (`check_score_provenance`), and so is a file cut off or of another run (`read_score_csv`)."""
    if f"{name}.csv" not in SCORE_FILES:
        raise ValueError(f"unknown score file {name!r}; use one of {[f[:-4] for f in SCORE_FILES]}")
    for run in runs:
        check_score_provenance(cfg, *run, required=True)
    frames = [read_run_metrics(cfg, run)[0] if name == "metrics" else
              read_score_csv(scores_dir(cfg, *run), f"{name}.csv", run_identity(*run), _run_fixes(*run)[0])
              for run in runs]
    frames = [f for f in frames if not f.empty] or frames[:1]
    return pd.concat(frames, ignore_index=True)


def read_source_coverage(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> pd.DataFrame:
    """The source coverage rows (one per run) of the Atari runs among `runs`, for a table; empty if none."""
    from paper_lib.ood.coverage import COVERAGE_COLUMNS

    atari = [run for run in runs if is_atari(run[0])]
    paths = [scores_dir(cfg, *run) / ATARI_SCORE_FILES[0] for run in atari]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:  # a run never scored (or scored before the check existed): first, as its fix is to score it
        raise FileNotFoundError(f"no source coverage file {missing[0]} ({len(missing)} missing): score those runs "
                                "again (`python -m paper_lib.pipeline.run_results score <env> <method> <seed>`).")
    for run in atari:
        check_score_provenance(cfg, *run, required=True)
    frames = [read_score_csv(scores_dir(cfg, *run), ATARI_SCORE_FILES[0], run_identity(*run), _run_fixes(*run)[0])
              for run in atari]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=[*COVERAGE_COLUMNS, "env",
                                                                                     "method", "seed"])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Per-run results: reward episodes (evaluate) and OOD scores (score); "
                                                 "`provenance` records what existing scores were made from (every "
                                                 "scored run of the profile, or the one given), rescoring nothing.")
    parser.add_argument("stage", choices=("evaluate", "score", "provenance"))
    parser.add_argument("env_id", nargs="?")
    parser.add_argument("method", nargs="?")
    parser.add_argument("seed", type=int, nargs="?")
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args(argv)
    given = [a is not None for a in (args.env_id, args.method, args.seed)]
    if not all(given) and (any(given) or args.stage != "provenance"):
        parser.error(f"{args.stage} needs a run: <env_id> <method> <seed>"
                     + (" (or none: every scored run of the profile)" if args.stage == "provenance" else ""))
    try:
        cfg = load_run_config(args.params)
        if args.stage == "provenance" and not any(given):
            runs = [run for run in cfg.runs() if (scores_dir(cfg, *run) / "metrics.csv").is_file()]
            written = record_provenance(cfg, runs)
            print(f"{len(written)} provenance record(s) written, {len(runs) - len(written)} already there "
                  f"({len(runs)} scored runs of profile {cfg.profile!r})")
            return
        if (args.env_id, args.method, args.seed) not in cfg.runs():
            raise ValueError(f"{args.env_id} {args.method} seed {args.seed} is not a run of profile {cfg.profile!r} "
                             f"(envs {cfg.envs}, methods {cfg.methods}, seeds {cfg.seeds})")
        if args.stage == "provenance":
            written = record_provenance(cfg, [(args.env_id, args.method, args.seed)])
            print(written[0] if written else "already recorded")
            return
        stage = evaluate_run if args.stage == "evaluate" else score_run_files
        print(stage(cfg, args.env_id, args.method, args.seed))
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")


if __name__ == "__main__":
    main()
