"""A study worker: runs trials of one study until it holds the requested number of finished trials.

    python -m paper_lib.study.worker --study ppo-HalfCheetah-v5-masksembles --trials 24
    python -m paper_lib.study.worker --study ppo-HalfCheetah-v5-masksembles --storage postgresql://u:p@host/db --trials 190
    python -m paper_lib.study.worker --all            # every study of the profile in turn (what the DVC stage runs)
    python -m paper_lib.study.worker --study ppo-Walker2d-v5-baseline --replace-other-recipe  # its env's recipe changed
    python -m paper_lib.study.worker --all --land-from sqlite:///../frozen/results/paper/studies/studies.db

Start the same command on as many machines (or cores) as you like: they share the study
through the storage. `--trials N` is the study's target of COMPLETE trials, not a per-worker
count, so the workers together finish exactly N (a trial started when the others already fill
the N slots is recorded as PRUNED with user attribute `surplus`, never run). A worker that
is killed loses only the trial it was running: its heartbeat stops, the next worker to look
marks it FAIL and queues a copy with the same settings and seed. A trial that fails by itself
(NaN loss, diverging env, an invalid configuration) is recorded FAIL with its `fail_reason`
and the study goes on with new settings, up to `--max-failures` such failures.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import optuna
import torch as th
from optuna.exceptions import UpdateFinishedTrialError
from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback, fail_stale_trials
from optuna.trial import FrozenTrial, TrialState

from paper_lib.pipeline.layout import REPLACED
from paper_lib.study.config import StudyConfig, StudySpec, load_study_config
from paper_lib.study.objective import Objective
from paper_lib.study.recipe import study_differences
from paper_lib.study.storage import experimental_ok, open_storage

DIRECTIONS = ("maximize", "maximize")
METRIC_NAMES = ("reward", "auroc")
LIVE = (TrialState.COMPLETE, TrialState.RUNNING, TrialState.WAITING)


class StopStudy(RuntimeError):
    """The study cannot go on as configured (too many trials failed by themselves)."""


def make_sampler(settings: dict[str, Any], seed: int | None) -> optuna.samplers.BaseSampler:
    """A multi-objective sampler from the budget's `sampler` entry (name plus the sampler's own arguments)."""
    kwargs = {k: v for k, v in settings.items() if k != "name"}
    name = settings["name"]
    try:
        if name == "tpe":
            # constant_liar: workers that sample at the same time avoid proposing the same settings
            return optuna.samplers.TPESampler(seed=seed, constant_liar=True, **kwargs)
        if name == "nsga2":
            return optuna.samplers.NSGAIISampler(seed=seed, **kwargs)
        return optuna.samplers.RandomSampler(seed=seed, **kwargs)
    except TypeError as err:
        raise ValueError(f"study sampler {name!r}: {err}; fix `sampler` in params.yaml's study budget") from None


def open_study(cfg: StudyConfig, spec: StudySpec, storage: RDBStorage, sampler_seed: int | None) -> optuna.Study:
    """Create or load the study; a stored study made with other settings is an error, never mixed into."""
    study = optuna.create_study(study_name=spec.name, storage=storage, directions=list(DIRECTIONS),
                                sampler=make_sampler(cfg.sampler, sampler_seed), load_if_exists=True)
    identity = {**spec.identity(), "profile": cfg.profile, "budget": cfg.budget, "objective": cfg.objective.__dict__,
                "eval_episodes": cfg.eval_episodes, "n_id_states": cfg.n_id_states,
                "max_episode_steps": cfg.max_episode_steps, "skip_first": cfg.skip_first, "seed": cfg.seed}
    stored = study.user_attrs.get("identity")
    if stored is None:
        study.set_user_attr("identity", identity)
        with experimental_ok():
            study.set_metric_names(list(METRIC_NAMES))
    elif stored != identity:
        differs = sorted(k for k in set(stored) | set(identity) if stored.get(k) != identity.get(k))
        raise ValueError(f"study {spec.name!r} in this storage was made with other settings ({differs}); its trials "
                         "would not be comparable. Use another storage, or delete it first: optuna delete-study "
                         f"--study-name {spec.name} --storage <URL>")
    wrong = study_differences(cfg, spec, study)
    if wrong:  # the env's recipe changed since (paper_lib/study/recipe.py)
        raise ValueError(f"study {spec.name!r} in this storage holds trials of another recipe ({wrong[0]}); new trials "
                         "would be mixed with them. Train it again: optuna delete-study --study-name "
                         f"{spec.name} --storage <URL> (copy the database first to keep the old trials)")
    return study


def _counts(study: optuna.Study) -> dict[TrialState, int]:
    counts = {state: 0 for state in TrialState}
    for trial in study.get_trials(deepcopy=False):
        counts[trial.state] += 1
    return counts


def _self_failures(study: optuna.Study) -> list[FrozenTrial]:
    """Trials that failed by themselves (they carry a fail_reason), not because their worker died."""
    return [t for t in study.get_trials(deepcopy=False, states=(TrialState.FAIL,)) if "fail_reason" in t.user_attrs]


class _Slotted:
    """The objective behind a check that the trial still has a slot among the study's first N live trials."""

    def __init__(self, objective: Callable[[optuna.Trial], Any], n_trials: int) -> None:
        self.objective, self.n_trials = objective, n_trials
        self.current: int | None = None

    def __call__(self, trial: optuna.Trial) -> Any:
        self.current = trial.number
        earlier = [t for t in trial.study.get_trials(deepcopy=False, states=LIVE) if t.number < trial.number]
        if len(earlier) >= self.n_trials:
            trial.set_user_attr("surplus", True)
            raise optuna.TrialPruned(f"the study already has {self.n_trials} trials finished or running")
        return self.objective(trial)


def run_worker(study: optuna.Study, objective: Callable[[optuna.Trial], Any], n_trials: int,
               max_failures: int | None = None, poll_seconds: float = 1.0,
               log: Callable[[str], None] = print) -> int:
    """Run trials until the study has `n_trials` COMPLETE ones; returns how many this worker finished.

    Waits (marking dead trials as it goes) while the other workers' running trials would fill the
    target, since one of them may still die and need a retry.
    """
    max_failures = max(10, n_trials) if max_failures is None else max_failures
    slotted, finished = _Slotted(objective, n_trials), 0
    while True:
        with experimental_ok():
            fail_stale_trials(study)
        counts = _counts(study)
        if counts[TrialState.COMPLETE] >= n_trials:
            return finished
        failures = _self_failures(study)
        if len(failures) >= max_failures:
            raise StopStudy(f"study {study.study_name!r}: {len(failures)} trials failed by themselves (last: trial "
                            f"{failures[-1].number}, {failures[-1].user_attrs['fail_reason'][:300]}); fix the cause "
                            "or raise --max-failures")
        pending = counts[TrialState.RUNNING] + counts[TrialState.WAITING]
        if counts[TrialState.COMPLETE] + pending >= n_trials and not counts[TrialState.WAITING]:
            time.sleep(poll_seconds)
            continue
        slotted.current = None
        try:
            study.optimize(slotted, n_trials=1, catch=(Exception,), gc_after_trial=True)
        except UpdateFinishedTrialError:  # its heartbeat was missed and another worker failed it: the retry counts
            log(f"{study.study_name}: trial {slotted.current} was declared dead while running; its retry replaces it")
            continue
        except KeyboardInterrupt:
            _requeue_interrupted(study, slotted.current, log)
            raise
        trial = _trial(study, slotted.current)
        if trial is not None:
            log(_describe(study.study_name, trial))
            finished += trial.state == TrialState.COMPLETE


def _requeue_interrupted(study: optuna.Study, number: int | None, log: Callable[[str], None]) -> None:
    """A worker stopped by Ctrl-C or SIGTERM queues its trial again, as a dead worker's would be."""
    trial = _trial(study, number)
    if trial is not None and trial.state == TrialState.FAIL and not trial.user_attrs.get("surplus"):
        storage = study._storage
        callback = getattr(storage, "get_heartbeat_stale_trial_callback", lambda: None)()
        with experimental_ok():
            (callback or RetryHeartbeatStaleTrialCallback())(study, trial)
        log(f"{study.study_name}: trial {number} interrupted; queued again with the same settings")


def _trial(study: optuna.Study, number: int | None) -> FrozenTrial | None:
    return next((t for t in study.get_trials(deepcopy=False) if t.number == number), None)


class WorkerStopped(KeyboardInterrupt):
    """SIGTERM, handled as Ctrl-C (the running trial is queued again), under a type of its own.

    A plain KeyboardInterrupt that arrives while CPython runs a string `exec` (dataclasses, namedtuple and
    others build code that way) sets a flag that makes a `python -m` process die by SIGINT at exit, even
    after the worker caught it and chose exit status 130; CPython checks the exact type, so a subclass keeps
    the status (a CI run lost that race once).
    """


def _interrupt(*_: Any) -> None:
    raise WorkerStopped


def _describe(name: str, trial: FrozenTrial) -> str:
    if trial.state == TrialState.COMPLETE:
        reward, auroc = trial.values
        return (f"{name}: trial {trial.number} COMPLETE reward={reward:.1f} auroc={auroc:.3f} "
                f"seed={trial.user_attrs.get('seed')} ({trial.user_attrs.get('seconds', 0):.0f} s)")
    reason = trial.user_attrs.get("fail_reason", "surplus" if trial.user_attrs.get("surplus") else "")
    return f"{name}: trial {trial.number} {trial.state.name} {reason[:300]}"


def replace_other_recipe(cfg: StudyConfig, name: str, storage_url: str | None = None,
                         log: Callable[[str], None] = print) -> Path | None:
    """Delete study `name` if it holds trials of another recipe (its env's recipe changed since), after copying the
    SQLite database under build/replaced/; return the copy, or None where there was nothing to replace."""
    url = storage_url or cfg.default_storage_url()
    if not url.startswith("sqlite:///"):
        raise ValueError(f"--replace-other-recipe keeps a copy of the database first, which it can do for SQLite only; "
                         f"for {url.split(':', 1)[0]} copy the study yourself (optuna copy-study), then delete it")
    if name not in optuna.get_all_study_names(storage=url):
        return None
    spec = cfg.study(name)
    wrong = study_differences(cfg, spec, optuna.load_study(study_name=name, storage=url))
    if not wrong:
        return None
    database = Path(url.removeprefix("sqlite:///"))
    copy = cfg.root / REPLACED / f"{database.stem}-before-{name}{database.suffix}"
    if copy.exists():
        raise ValueError(f"{copy} already holds a replaced copy; look at it and delete it, then run again")
    copy.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(database, copy)
    optuna.delete_study(study_name=name, storage=url)
    log(f"{name}: its trials were of another recipe ({wrong[0]}); deleted, the database before is {copy}")
    return copy


def land_study(cfg: StudyConfig, name: str, source_url: str, storage_url: str | None = None,
               log: Callable[[str], None] = print) -> bool:
    """Copy study `name` from `source_url` (a training worktree's database) into this storage once it is done there
    (its trial target of COMPLETE trials, every trial of today's recipe) and this storage's is not; a study of another
    recipe here is replaced (replace_other_recipe keeps a copy). True if it landed."""
    url = storage_url or cfg.default_storage_url()
    spec = cfg.study(name)
    if name not in optuna.get_all_study_names(storage=source_url):
        return False
    source = optuna.load_study(study_name=name, storage=source_url)
    done = sum(t.state == TrialState.COMPLETE for t in source.get_trials(deepcopy=False))
    if done < spec.n_trials or study_differences(cfg, spec, source):
        return False
    replace_other_recipe(cfg, name, url, log)
    if name in optuna.get_all_study_names(storage=url):
        return False  # already of today's recipe here: nothing to land
    optuna.copy_study(from_study_name=name, from_storage=source_url, to_storage=url)
    log(f"{name}: landed {done} COMPLETE trials from {source_url}")
    return True


def run_study(cfg: StudyConfig, name: str, storage_url: str | None = None, n_trials: int | None = None,
              max_failures: int | None = None, sampler_seed: int | None = None,
              log: Callable[[str], None] = print) -> optuna.Study:
    """Open study `name` of `cfg` in `storage_url` (default: the profile's SQLite file) and work on it."""
    spec = cfg.study(name)
    storage = open_storage(storage_url or cfg.default_storage_url(), cfg.heartbeat)
    study = open_study(cfg, spec, storage, sampler_seed)
    target = spec.n_trials if n_trials is None else n_trials
    run_worker(study, Objective(cfg, spec), target, max_failures=max_failures,
               poll_seconds=min(5.0, cfg.heartbeat.interval), log=log)
    return study


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     epilog="Study names are <algo>-<env>-<method>; --list prints the profile's.")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--study", help="e.g. ppo-HalfCheetah-v5-masksembles")
    which.add_argument("--all", action="store_true", help="every study of the profile, one after the other")
    which.add_argument("--list", action="store_true", help="print the profile's study names and exit")
    parser.add_argument("--storage", default=None,
                        help="Optuna database URL (default: sqlite:///results/<profile>/studies/studies.db)")
    parser.add_argument("--trials", type=int, default=None,
                        help="COMPLETE trials the study should hold (default: the profile's n_trials)")
    parser.add_argument("--profile", default=None, help="run profile (default: params.yaml's active profile); its study budget is "
                        "study.budget_of_profile's entry for it, else its own")
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--sampler-seed", type=int, default=None,
                        help="seed of this worker's sampler (default: random; give each worker its own)")
    parser.add_argument("--max-failures", type=int, default=None,
                        help="stop once this many trials failed by themselves (default: the trial target, at least 10)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per trial")
    parser.add_argument("--land-from", metavar="URL", help="copy in the studies done in this database (a training "
                        "worktree's) where this storage's are missing or of another recipe, instead of running trials")
    parser.add_argument("--replace-other-recipe", action="store_true",
                        help="delete a study whose trials were trained with an older recipe of its env first (the "
                             "SQLite file before is copied under build/replaced/), then train it again")
    args = parser.parse_args(argv)
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    logging.getLogger("optuna").setLevel(logging.ERROR)
    signal.signal(signal.SIGTERM, _interrupt)  # a stopped worker queues its trial again, like Ctrl-C
    try:
        if args.trials is not None and args.trials < 1:
            raise ValueError(f"--trials must be a positive number of trials, got {args.trials}")
        if args.threads < 1:
            raise ValueError(f"--threads must be a positive number of torch threads, got {args.threads}")
        cfg = load_study_config(args.params, args.profile)
        if args.list:
            print("\n".join(cfg.studies))
            return
        th.set_num_threads(args.threads)
        names = list(cfg.studies) if args.all else [cfg.study(args.study).name]
        log = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
        if args.land_from:
            landed = [name for name in names if land_study(cfg, name, args.land_from, args.storage, log)]
            print(f"{len(landed)} stud{'y' if len(landed) == 1 else 'ies'} landed: {landed}")
            return
        for name in names:
            if args.replace_other_recipe:
                replace_other_recipe(cfg, name, args.storage, log)
            run_study(cfg, name, args.storage, args.trials, args.max_failures, args.sampler_seed, log=log)
    except (ValueError, StopStudy) as err:
        parser.exit(2 if isinstance(err, ValueError) else 1, f"error: {err}\n")
    except KeyboardInterrupt:
        parser.exit(130, "interrupted; the running trial was queued again\n")


if __name__ == "__main__":
    main()
