"""A study database as a resume point: Optuna studies still training outlive the machine (scripts/resume_points.sh).

A study worker in the training worktree (issue 38's queue) writes its trials to that tree's own
results/<profile>/studies/studies.db; the repository's copy only changes when the finished studies land
(`python -m paper_lib.study.worker --all --land-from sqlite:///TREE/results/<profile>/studies/studies.db`).
    python scripts/studies_resume_point.py save TREE_DB REPO_DB STORED_DB
copies TREE_DB to STORED_DB (SQLite's online backup: consistent while a worker writes) unless every COMPLETE
trial of it is already in REPO_DB (landed, or nothing trained yet: STORED_DB is removed) or in STORED_DB (the
same trials as saved before: its bytes are kept, as heartbeats alone rewrite the file).
Trials are compared by study name, parameters and objective values, which `optuna.copy_study` keeps.
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
from pathlib import Path

import optuna
from optuna.trial import TrialState

Trial = tuple[str, tuple, tuple]


def complete_trials(db: Path) -> set[Trial]:
    """Every COMPLETE trial of every study in the SQLite file `db`, as (study, sorted params, values)."""
    if not db.is_file():
        return set()
    url = f"sqlite:///{db.resolve()}"
    trials: set[Trial] = set()
    for name in optuna.get_all_study_names(storage=url):
        for trial in optuna.load_study(study_name=name, storage=url).get_trials(
                deepcopy=False, states=(TrialState.COMPLETE,)):
            trials.add((name, tuple(sorted((k, repr(v)) for k, v in trial.params.items())), tuple(trial.values)))
    return trials


def save(tree_db: Path, repo_db: Path, stored_db: Path) -> str:
    """Carry tree_db's trials that the repository lacks; return what was done, in words."""
    ours = complete_trials(tree_db)
    if ours <= complete_trials(repo_db):
        stored_db.unlink(missing_ok=True)
        return "nothing to carry (every COMPLETE trial is in the repository's database)"
    if ours == complete_trials(stored_db):
        return f"kept {stored_db} ({len(ours)} COMPLETE trials, as saved before)"
    stored_db.parent.mkdir(parents=True, exist_ok=True)
    partial = stored_db.with_suffix(".tmp")
    partial.unlink(missing_ok=True)
    with sqlite3.connect(tree_db) as source, sqlite3.connect(partial) as target:
        source.backup(target)
    partial.replace(stored_db)  # a kill leaves the previous copy
    return f"saved {stored_db} ({len(ours)} COMPLETE trials)"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=["save"])
    parser.add_argument("tree_db", type=Path)
    parser.add_argument("repo_db", type=Path)
    parser.add_argument("stored_db", type=Path)
    args = parser.parse_args(argv)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if not args.tree_db.is_file():
        sys.exit(f"error: {args.tree_db} is not a study database: give the training tree's studies.db")
    print(save(args.tree_db, args.repo_db, args.stored_db))


if __name__ == "__main__":
    main()
