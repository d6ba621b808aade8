"""Appendix E: the same env and method trained at several hidden-layer widths (Ant 64/128, Walker2d 64/96/128).

Runs come from params.yaml's `study.scaling.<profile>`: widths per env, methods, seeds, a training
budget (null: each env's full budget) and `fixed` algorithm settings. Each run is an ordinary
training run (`paper_lib.agents.training.train_run`, so it resumes after a kill) with the env's paper
hyperparameters and every hidden layer set to the width, Masksembles included.

    python -m paper_lib.study.scaling             # train every run not done yet, and evaluate it once it is
    python -m paper_lib.study.scaling --evaluate  # only evaluate trained runs that have no evaluation file yet
    python -m paper_lib.study.scaling --list      # the runs, their folders and status
    python -m paper_lib.study.scaling --env Walker2d-v5 --method masksembles --width 64  # only these runs
    python -m paper_lib.study.scaling --land ../frozen  # copy in the runs a training queue finished there

A run's final reward is measured once, when it lands, and kept beside its checkpoint (final_evaluation.json,
with the checkpoint's SHA-256): notebook 10 only reads these files, so a rebuild never steps an env and gives the
same numbers on any CPU (MuJoCo's last float bits differ across CPUs and chaotic episodes amplify them).

A run counts as trained only if its config.json is what params.yaml trains today (the env's recipe, the width,
the budget: paper_lib.pipeline.landing's comparison). When an env's recipe changes (issue 38's Walker2d), its old
runs show as "another recipe" in notebook 10 and are left out of every figure and table, and training moves
each one aside (build/replaced/, outside results/) before training it again.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from paper_lib.common.io import write_json_atomic
from paper_lib.common.provenance import file_digest
from paper_lib.methods.networks import METHODS
from paper_lib.pipeline.config import PARAMS_FILE, check_keys, read_params
from paper_lib.pipeline.landing import differences, expected_for, trained_config
from paper_lib.pipeline.layout import REPLACED, Layout
from paper_lib.study.config import budget_label, resolve_budget
from paper_lib.study.space import agent_kwargs

#: A run's final evaluation, beside its model.zip.
EVALUATION_FILE = "final_evaluation.json"
#: The evaluation env's seed is this plus the run's seed (the training envs use the run's seed).
EVAL_SEED_OFFSET = 10_000

KEYS = ("widths", "methods", "seeds", "total_timesteps", "fixed", "eval_episodes")


@dataclass(frozen=True)
class ScalingRun:
    env_id: str
    method: str
    width: int
    seed: int

    def __str__(self) -> str:
        return f"{self.env_id} {self.method} width {self.width} seed {self.seed}"


@dataclass(frozen=True)
class ScalingConfig:
    profile: str  # the run profile: results go to results/<profile>/scaling
    budget: str  # the entry of study.scaling these runs use
    runs: list[ScalingRun]
    total_timesteps: int | None
    fixed: dict[str, Any]
    eval_episodes: int
    hyperparameters: dict[str, dict[str, Any]]
    root: Path

    def run_dir(self, run: ScalingRun) -> Path:
        return Layout.of(self.root, self.profile).scaling_dir(run.env_id, run.method, run.width, run.seed)

    def agent_kwargs(self, run: ScalingRun) -> dict[str, Any]:
        return agent_kwargs({"width": run.width}, self.fixed, self.hyperparameters[run.env_id])

    def caption(self) -> str:
        steps = self.total_timesteps or "each env's full"
        seeds = sorted({r.seed for r in self.runs})
        return (f"{budget_label(self.profile, self.budget)}: {steps} training steps per run, {len(seeds)} seed(s) {seeds}, "
                f"{self.eval_episodes} deterministic evaluation episodes; the paper: 2-3 runs at the full budget")


def load_scaling_config(path: str | Path = PARAMS_FILE, profile: str | None = None) -> ScalingConfig:
    path = Path(path)
    params = read_params(path)
    profile = profile or (params.get("run") or {}).get("profile")
    section = ((params.get("study") or {}).get("scaling")) or {}
    budget = resolve_budget(params, profile, path, "scaling", sorted(section))
    where = f"{path}: study.scaling.{budget}"
    raw = check_keys(section[budget], where, KEYS, KEYS, fix="copy them from another budget of study.scaling")
    hps = params["hyperparameters"]
    if not isinstance(raw["widths"], dict) or not raw["widths"]:
        raise ValueError(f"{where}.widths must map env ids to lists of widths, e.g. {{Ant-v5: [64, 128]}}")
    for env_id, widths in raw["widths"].items():
        if env_id not in hps:
            raise ValueError(f"{where}.widths: unknown env {env_id!r}; params.yaml has hyperparameters for {sorted(hps)}")
        if not isinstance(widths, list) or not widths or not all(
                isinstance(w, int) and not isinstance(w, bool) and w >= 10 for w in widths):
            raise ValueError(f"{where}.widths.{env_id} must be a list of integer widths >= 10, got {widths!r}")
    if not isinstance(raw["methods"], list) or not raw["methods"] or not set(raw["methods"]) <= set(METHODS):
        raise ValueError(f"{where}.methods must be a non-empty list from {METHODS}, got {raw['methods']!r}")
    if not isinstance(raw["seeds"], list) or not raw["seeds"] or not all(
            isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in raw["seeds"]):
        raise ValueError(f"{where}.seeds must be a non-empty list of integers >= 0, got {raw['seeds']!r}")
    steps = raw["total_timesteps"]
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise ValueError(f"{where}.total_timesteps must be a positive integer or null, got {steps!r}")
    episodes = raw["eval_episodes"]
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"{where}.eval_episodes must be a positive integer, got {episodes!r}")
    if not isinstance(raw["fixed"], dict):
        raise ValueError(f"{where}.fixed must be a mapping of algorithm settings, got {raw['fixed']!r}")
    for name, listed in [("methods", raw["methods"]), ("seeds", raw["seeds"]),
                         *((f"widths.{env_id}", widths) for env_id, widths in raw["widths"].items())]:
        twice = sorted({x for x in listed if listed.count(x) > 1}, key=str)
        if twice:  # each run would be listed, trained and counted twice
            raise ValueError(f"{where}.{name} must list each entry once, got {twice} twice in {listed!r}; "
                             f"delete the repeats in {path}")
    runs = [ScalingRun(env_id, method, width, seed) for env_id, widths in raw["widths"].items()
            for method in raw["methods"] for width in widths for seed in raw["seeds"]]
    return ScalingConfig(profile, budget, runs, steps, dict(raw["fixed"]), episodes, hps, path.parent)


def recipe_differences(cfg: ScalingConfig, run: ScalingRun) -> list[str]:
    """Every training setting in which the run's finished checkpoint differs from what params.yaml trains today
    (empty: it is this run); raises FileNotFoundError while the run has no finished checkpoint."""
    expected = expected_for(run.env_id, run.method, run.seed, cfg.total_timesteps, cfg.agent_kwargs(run))
    return differences(trained_config(cfg.run_dir(run)), expected)


def run_status(cfg: ScalingConfig, run: ScalingRun) -> str:
    """TRAINED, NOT_TRAINED, or OTHER_RECIPE (finished, but trained with settings params.yaml no longer gives)."""
    try:
        return OTHER_RECIPE if recipe_differences(cfg, run) else TRAINED
    except FileNotFoundError:
        return NOT_TRAINED


def is_done(cfg: ScalingConfig, run: ScalingRun) -> bool:
    """A finished checkpoint of this run trained as params.yaml trains it (so a re-run trains only the rest)."""
    return run_status(cfg, run) == TRAINED


def move_aside(cfg: ScalingConfig, run: ScalingRun) -> Path:
    """Move a run of another recipe (and any resume point of it) under build/replaced/, so it is trained afresh."""
    folder = cfg.run_dir(run)
    target = cfg.root / REPLACED / folder.relative_to(cfg.root)
    if target.exists():
        raise FileExistsError(f"{target} already holds a replaced run; look at it and delete it, then run again")
    target.parent.mkdir(parents=True, exist_ok=True)
    resume = folder.parent / f".{folder.name}.resume"
    if resume.exists():
        shutil.move(resume, target.parent / resume.name)
    shutil.move(folder, target)
    return target


def train_missing(cfg: ScalingConfig, threads: int = 1, log=print) -> list[Path]:
    """Train (or resume) every run that has no finished checkpoint yet; evaluate each once it has one."""
    from paper_lib.agents.training import train_run

    done = []
    for run in cfg.runs:
        status = run_status(cfg, run)
        if status == OTHER_RECIPE:
            log(f"scaling: {run} was trained with another recipe ({'; '.join(recipe_differences(cfg, run))}); "
                f"moved to {move_aside(cfg, run)}")
        if status != TRAINED:
            log(f"scaling: training {run}")
            done.append(train_run(run.env_id, run.method, run.seed, cfg.run_dir(run),
                                  total_timesteps=cfg.total_timesteps, agent_kwargs=cfg.agent_kwargs(run),
                                  torch_threads=threads))
        if not is_evaluated(cfg, run):
            log(f"scaling: evaluating {run}")
            evaluate_run(cfg, run)
    return done


def land_from(cfg: ScalingConfig, tree: Path, log=print) -> list[ScalingRun]:
    """Land the runs trained outside (a training queue's worktree `tree`): copy each run finished there and trained as
    params.yaml trains it, where this tree's is not, after moving this tree's folder aside; then evaluate it once."""
    if not (Path(tree) / "results").is_dir():
        raise ValueError(f"{tree} has no results/ folder: give the root of the worktree the runs were trained in")
    there = dataclasses.replace(cfg, root=Path(tree))
    landed = []
    for run in cfg.runs:
        if run_status(cfg, run) == TRAINED or run_status(there, run) != TRAINED:
            continue
        if cfg.run_dir(run).exists():
            log(f"scaling: {run}: the run here moved to {move_aside(cfg, run)}")
        shutil.copytree(there.run_dir(run), cfg.run_dir(run))
        evaluate_run(cfg, run)
        log(f"scaling: landed {run} from {there.run_dir(run)}")
        landed.append(run)
    return landed


def evaluate_run(cfg: ScalingConfig, run: ScalingRun) -> Path:
    """Play the run's deterministic evaluation episodes once and keep their rewards beside the checkpoint."""
    from paper_lib.agents.checkpoints import load_checkpoint
    from paper_lib.study.objective import evaluation_episodes

    folder = cfg.run_dir(run)
    checkpoint = load_checkpoint(folder, run.env_id, run.method, run.seed)
    eval_seed = EVAL_SEED_OFFSET + run.seed
    rewards = evaluation_episodes(checkpoint, cfg.eval_episodes, eval_seed, deterministic=True)
    return write_json_atomic(folder / EVALUATION_FILE, {
        "env": run.env_id, "method": run.method, "width": run.width, "seed": run.seed, "eval_seed": eval_seed,
        "deterministic": True, "episodes": cfg.eval_episodes, "rewards": rewards,
        "checkpoint_sha256": file_digest(folder / "model.zip")})


def is_evaluated(cfg: ScalingConfig, run: ScalingRun) -> bool:
    return (cfg.run_dir(run) / EVALUATION_FILE).is_file()


def evaluate_missing(cfg: ScalingConfig, log=print) -> list[Path]:
    """Evaluate every trained run that has no evaluation file yet (a run lands with its evaluation)."""
    written = []
    for run in trained_runs(cfg):
        if not is_evaluated(cfg, run):
            log(f"scaling: evaluating {run}")
            written.append(evaluate_run(cfg, run))
    return written


#: `progress` status of a run trained as params.yaml says, of one not finished, and of one of an older recipe.
TRAINED, NOT_TRAINED, OTHER_RECIPE = "trained", "not trained", "another recipe"


def progress(cfg: ScalingConfig) -> pd.DataFrame:
    """Every run with its status: the notebook draws the trained ones while the others still train (hours)."""
    rows = [{"env": r.env_id, "method": r.method, "width": r.width, "seed": r.seed,
             "status": run_status(cfg, r), "folder": str(cfg.run_dir(r))} for r in cfg.runs]
    return pd.DataFrame(rows, columns=["env", "method", "width", "seed", "status", "folder"])


def progress_caption(status: pd.DataFrame) -> str:
    """'7 of 20 scaling runs trained', for captions and titles (and how many wait with an older recipe)."""
    stale = int((status["status"] == OTHER_RECIPE).sum())
    older = f" ({stale} more of an older recipe, to train again)" if stale else ""
    return f"{int((status['status'] == TRAINED).sum())} of {len(status)} scaling runs trained{older}"


def trained_runs(cfg: ScalingConfig) -> list[ScalingRun]:
    return [run for run in cfg.runs if is_done(cfg, run)]


def training_curves(cfg: ScalingConfig, runs: list[ScalingRun] | None = None) -> pd.DataFrame:
    """The training curves of `runs` (default: every run, all of which must be trained), tagged with env,
    method, width and seed."""
    frames = []
    for run in cfg.runs if runs is None else runs:
        path = cfg.run_dir(run) / "training_curve.csv"
        if not path.is_file():
            raise FileNotFoundError(f"{path} is missing; train it with `python -m paper_lib.study.scaling`")
        frames.append(pd.read_csv(path).assign(env=run.env_id, method=run.method, width=run.width, seed=run.seed))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(
        columns=["timesteps", "reward", "env", "method", "width", "seed"])


def read_evaluation(cfg: ScalingConfig, run: ScalingRun) -> list[float]:
    """The rewards in the run's evaluation file, after checking that the file is this run's, made from the checkpoint
    beside it, with the episodes params.yaml asks for."""
    folder = cfg.run_dir(run)
    path = folder / EVALUATION_FILE
    fix = f"evaluate it again with `python -m paper_lib.study.scaling --evaluate` after deleting {path}"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: the run has no final evaluation; "
                                "make it with `python -m paper_lib.study.scaling --evaluate`")
    record = json.loads(path.read_text())
    want = {"env": run.env_id, "method": run.method, "width": run.width, "seed": run.seed,
            "episodes": cfg.eval_episodes, "checkpoint_sha256": file_digest(folder / "model.zip")}
    wrong = {key: (record.get(key), value) for key, value in want.items() if record.get(key) != value}
    if wrong or len(record.get("rewards") or []) != cfg.eval_episodes:
        what = "; ".join(f"{key} is {got!r}, this run's is {value!r}" for key, (got, value) in wrong.items())
        raise ValueError(f"{path} does not belong to this run ({what or 'wrong number of rewards'}): {fix}")
    return [float(r) for r in record["rewards"]]


def final_rewards(cfg: ScalingConfig, runs: list[ScalingRun] | None = None) -> pd.DataFrame:
    """Deterministic evaluation reward of `runs` (default: every run), one row per episode, read from the runs'
    evaluation files (never simulated here)."""
    rows = []
    for run in cfg.runs if runs is None else runs:
        rewards = read_evaluation(cfg, run)
        rows += [{"env": run.env_id, "method": run.method, "width": run.width, "seed": run.seed, "episode": i,
                  "reward": float(r)} for i, r in enumerate(rewards)]
    return pd.DataFrame(rows, columns=["env", "method", "width", "seed", "episode", "reward"])


def width_reading(table: pd.DataFrame, status: pd.DataFrame) -> pd.DataFrame:
    """Per env and method: the change of the mean final reward from the narrowest to the widest layers, read
    only once all its runs are trained (a missing width would make the change meaningless)."""
    rows = []
    for (env, method), runs in status.groupby(["env", "method"], sort=False):
        row = {"env": env, "method": method, "narrowest": int(runs["width"].min()),
               "widest": int(runs["width"].max()), "change": np.nan, "read": False}
        if (runs["status"] == TRAINED).all():
            group = table[(table["env"] == env) & (table["method"] == method)].sort_values("width")
            row.update(change=float(group["mean"].iloc[-1] - group["mean"].iloc[0]), read=True)
        rows.append(row)
    return pd.DataFrame(rows, columns=["env", "method", "narrowest", "widest", "change", "read"])


#: Appendix E's findings, per env and method: the outcomes of widening that agree with the paper. Ant: "only
#: Masksembles show improved performance ... The other methods may even drop"; Walker2d: "a clear improvement for
#: Masksembles, and a slight improvement for MC Dropout, while the baseline and Ensemble policies are mainly
#: unaffected".
PAPER_SCALING: dict[tuple[str, str], tuple[str, ...]] = {
    ("Ant-v5", "masksembles"): ("up",), ("Ant-v5", "baseline"): ("flat", "down"),
    ("Ant-v5", "mc_dropout"): ("flat", "down"), ("Ant-v5", "ensemble"): ("flat", "down"),
    ("Walker2d-v5", "masksembles"): ("up",), ("Walker2d-v5", "mc_dropout"): ("up",),
    ("Walker2d-v5", "baseline"): ("flat",), ("Walker2d-v5", "ensemble"): ("flat",),
}
#: A change of the mean final reward within this share of the narrowest width's mean counts as "flat".
FLAT_SHARE = 0.05


def paper_comparison(change: pd.DataFrame, table: pd.DataFrame) -> pd.DataFrame:
    """Each read (env, method) of `width_reading` that appendix E speaks about: our direction (the change as a
    share of the narrowest width's mean reward; within +-FLAT_SHARE is "flat") beside the paper's."""
    rows = []
    for row in change[change["read"]].itertuples():
        expected = PAPER_SCALING.get((row.env, row.method))
        if expected is None:
            continue
        narrow = table[(table["env"] == row.env) & (table["method"] == row.method) & (table["width"] == row.narrowest)]
        share = row.change / abs(float(narrow["mean"].iloc[0]))
        ours = "flat" if abs(share) <= FLAT_SHARE else ("up" if share > 0 else "down")
        rows.append({"env": row.env, "method": row.method, "relative_change": share, "ours": ours,
                     "paper": " or ".join(expected), "agrees": ours in expected})
    return pd.DataFrame(rows, columns=["env", "method", "relative_change", "ours", "paper", "agrees"])


def final_table(final: pd.DataFrame) -> pd.DataFrame:
    """Mean ± std of the final reward per env, method and width (std over episodes and seeds)."""
    return (final.groupby(["env", "method", "width"])["reward"].agg(mean="mean", std=lambda r: float(np.std(r)),
                                                                   episodes="size").reset_index())


def select(cfg: ScalingConfig, env_id: str | None = None, method: str | None = None, width: int | None = None,
           seed: int | None = None) -> ScalingConfig:
    """The config restricted to the runs matching every given filter (a training queue trains one run a line)."""
    wanted = {"env_id": env_id, "method": method, "width": width, "seed": seed}
    runs = [r for r in cfg.runs if all(v is None or getattr(r, k) == v for k, v in wanted.items())]
    if not runs:
        given = ", ".join(f"{k} {v}" for k, v in wanted.items() if v is not None)
        raise ValueError(f"no scaling run of budget {cfg.budget!r} has {given}; `--list` shows them all")
    return dataclasses.replace(cfg, runs=runs)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Train appendix E's scaling runs (resumable).")
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--profile", default=None, help="budget profile (default: params.yaml's active profile)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--list", action="store_true", help="print the runs and their folders")
    parser.add_argument("--evaluate", action="store_true", help="only evaluate trained runs that lack an evaluation")
    parser.add_argument("--land", metavar="TREE", help="copy in every run finished in TREE (a training worktree) as "
                        "params.yaml trains it, where this tree's is not, and evaluate it")
    parser.add_argument("--env", help="only the runs of this env")
    parser.add_argument("--method", help="only the runs of this method")
    parser.add_argument("--width", type=int, help="only the runs of this width")
    parser.add_argument("--seed", type=int, help="only the runs of this seed")
    args = parser.parse_args(argv)
    try:
        cfg = select(load_scaling_config(args.params, args.profile), args.env, args.method, args.width, args.seed)
        if args.list:
            for run in cfg.runs:
                print(f"{run}: {cfg.run_dir(run)} ({run_status(cfg, run)})")
            return
        if args.evaluate:
            evaluate_missing(cfg)
            return
        if args.land:
            landed = land_from(cfg, Path(args.land))
            print(f"{len(landed)} run(s) landed; {progress_caption(progress(cfg))}")
            return
        if args.threads < 1:
            raise ValueError(f"--threads must be a positive number of torch threads, got {args.threads}")
        train_missing(cfg, args.threads)
    except (ValueError, FileNotFoundError, FileExistsError) as err:
        parser.exit(2, f"error: {err}\n")


if __name__ == "__main__":
    main()
