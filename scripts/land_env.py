"""Land every run of one env trained outside DVC with a new recipe: its matrix runs and its independent members.

An env's new recipe lands all at once (issue 38): its entry moves from params.yaml's `retraining` into
`hyperparameters` by hand first (the commit that lands the runs holds both), then
    python scripts/land_env.py ENV TRAINING_TREE [--dry-run]
1. checks before writing anything: ENV is no longer under `retraining`; every run of the active profile for ENV
   and every independent member of ENV (params.yaml `ensembles`) has finished in TRAINING_TREE (the worktree
   scripts/train_queue.sh trained in) and was trained as params.yaml trains it (paper_lib.pipeline.landing);
2. copies their checkpoint folders into this tree, replacing the old runs';
3. collects and evaluates the matrix runs with HEAD's code and records their stages (scripts/land_run.sh);
4. moves aside, into the env's `replaced/` folder outside results/ (build/landed/), the independent combinations'
   datasets, evaluations and scores of ENV, which were made from the replaced members, so that
   `dvc repro ensembles_scores` makes them again from the new ones (notebook 11's readers refuse them otherwise).
Then: `dvc repro ensembles_scores`, `make reproduce`, git add the env's checkpoints and results, and drop the runs'
resume points (`scripts/resume_points.sh save TRAINING_TREE` without --keep-landed). `--dry-run` stops after 1.
An env whose `own` runs the ensembles part trains is refused: their twins would need retraining too.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

from paper_lib.experiments import ensembles as ens
from paper_lib.pipeline.config import load_run_config, read_params
from paper_lib.pipeline.landing import differences, expected_config, expected_for, trained_config

ROOT = Path(__file__).resolve().parents[1]
MOVED_ASIDE = Path("build/landed")


def runs_to_land(env_id: str, tree: Path) -> list[tuple[Path, Path, str]]:
    """(source folder, destination folder, what) of every run of `env_id` to land; raise naming every problem."""
    cfg = load_run_config()
    if env_id in (read_params().get("retraining") or {}):
        raise ValueError(f"params.yaml lists {env_id} under `retraining`: move retraining.{env_id} into "
                         f"hyperparameters.{env_id} first (its runs were trained with it)")
    if env_id not in cfg.envs:
        raise ValueError(f"{env_id} is not an env of profile {cfg.profile!r}: {cfg.envs}")
    ecfg = ens.load_ensembles_config()
    if env_id in ecfg.own_envs:
        raise ValueError(f"{env_id} has `own` runs in params.yaml's ensembles section: land_env does not retrain "
                         "their twins; land the env by hand (docs/pipeline.md)")
    runs, problems = [], []
    for run in (r for r in cfg.runs() if r[0] == env_id):
        dest = cfg.checkpoint_dir(*run)
        runs.append((tree / dest, dest, " ".join(map(str, run))))
        problems += _problems(tree / dest, lambda: expected_config(cfg, *run), runs[-1][2])
    if env_id in ecfg.envs:
        steps, kwargs = ens.member_train_args(ecfg, env_id)
        for seed in ecfg.member_seeds:
            dest = ecfg.member_dir(env_id, seed)
            runs.append((tree / dest, dest, f"{env_id} independent member {seed}"))
            problems += _problems(tree / dest, lambda: expected_for(env_id, "baseline", seed, steps, kwargs),
                                  runs[-1][2])
    if problems:
        raise ValueError("not landing anything:\n  " + "\n  ".join(problems))
    return runs


def _problems(folder: Path, expected, what: str) -> list[str]:
    try:
        wrong = differences(trained_config(folder), expected())
    except FileNotFoundError as err:
        return [f"{what}: {err}"]
    return [f"{what} ({folder}): {'; '.join(wrong)}"] if wrong else []


def move_aside_combinations(env_id: str) -> list[Path]:
    """Move the env's independent combination artifacts (made from the replaced members) under build/landed/."""
    ecfg = ens.load_ensembles_config()
    if env_id not in ecfg.envs:
        return []
    moved = []
    for members in ecfg.combinations():
        for path in (ecfg.combination_dataset(env_id, members), ecfg.combination_evaluation(env_id, members),
                     ens.combination_scores_dir(ecfg, env_id, members)):
            if path.exists():
                target = MOVED_ASIDE / path
                target.parent.mkdir(parents=True, exist_ok=True)
                if target.exists():
                    shutil.rmtree(target) if target.is_dir() else target.unlink()
                shutil.move(str(path), str(target))
                moved.append(path)
    return moved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("env")
    parser.add_argument("tree", type=Path, help="the worktree the runs were trained in")
    parser.add_argument("--dry-run", action="store_true", help="only check, write nothing")
    args = parser.parse_args()
    try:
        runs = runs_to_land(args.env, args.tree.resolve())
    except ValueError as err:
        sys.exit(f"error: {err}")
    print(f"{len(runs)} runs of {args.env} finished and trained as params.yaml says")
    if args.dry_run:
        return
    for source, dest, what in runs:
        staging = dest.with_name(dest.name + ".landing")
        shutil.rmtree(staging, ignore_errors=True)
        shutil.copytree(source, staging)
        shutil.rmtree(dest, ignore_errors=True)
        staging.rename(dest)
        print(f"copied {what}: {source} -> {dest}")
    cfg = load_run_config()
    matrix = [str(x) for run in cfg.runs() if run[0] == args.env for x in run]
    subprocess.run(["bash", str(ROOT / "scripts/land_run.sh"), *matrix], check=True)
    for path in move_aside_combinations(args.env):
        print(f"moved aside {path} (made from the replaced members) -> {MOVED_ASIDE / path}")
    print("next: dvc repro ensembles_scores; make reproduce; git add the env's checkpoints and results")


if __name__ == "__main__":
    main()
