"""Ensembles examined: independently trained ensembles (paper appendix B.2) and the `own` assignment.

Which runs exist, how they are trained, where they live, their ID/OOD states, reward episodes
and OOD scores; the tables and figure are in `paper_lib.experiments.ensembles_report`, shown by
notebooks/11_ensembles.ipynb.

params.yaml's `ensembles` section holds the paper's rule and, per budget profile, the runs:

    ensembles:
      rule: {budget_fraction: 0.25, epochs_factor: 4, ensemble_size: 4}
      profiles:
        cpu:
          independent: {envs: [Walker2d-v5, ...], member_seeds: [0, 1, 2, 3, 4], total_timesteps: null}
          own_vs_shared: {envs: [HalfCheetah-v5, Swimmer-v5], methods: [masksembles, ensemble], seeds: [0, 1, 2]}

- **Independent members**: baseline agents, each trained alone with `budget_fraction` of the
  full budget (`total_timesteps`; null: the profile's `run.total_timesteps`, else the env's) and
  `epochs_factor` times its `n_epochs` (the profile's override, else the env's): as many gradient
  updates as a full run from a quarter of the interactions (appendix B.2). Every
  `ensemble_size`-of-n combination of the members is assembled into one
  `IndependentEnsemblePolicy`, with no retraining.
- **own vs shared**: `assignment="own"` runs with the main matrix's recipe and budget; their
  `shared` twins are the main matrix's runs. A pair is compared only if the two runs' training
  settings agree in everything but the assignment.

Both parts mirror the main results tree (`RunConfig` with the profile `<profile>/independent`
or `<profile>/own`), so the main pipeline's per-run functions (collect, evaluate, score) and
readers serve the `own` runs unchanged. Under results/<profile>/:

    independent/checkpoints/<env>/baseline/seed<s>/           one member
    independent/{datasets,evaluations}/<env>/members-0-1-2-3.{npz,csv}, independent/scores/<env>/members-0-1-2-3/
        metrics.csv, provenance.json (the combination, and the SHA-256 of its dataset and of each member's
        model.zip and vecnormalize.pkl: readers refuse scores whose inputs changed, or without the record)
    own/{checkpoints,datasets,evaluations,scores}/<env>/<method>/seed<s>...   as the main tree, assignment own
    {checkpoints,datasets,evaluations,scores}/<env>/<method>/seed<s>...       the shared twins: the main tree

    python -m paper_lib.experiments.ensembles queue [--resume-root /work/resume]   # training commands of the runs still missing
    python -m paper_lib.experiments.ensembles train {independent,own} [--env E] [--method M] [--seed S]
    python -m paper_lib.experiments.ensembles collect     # ID/OOD states of every combination and run that lacks them
    python -m paper_lib.experiments.ensembles evaluate    # reward episodes and OOD scores of the same
    python -m paper_lib.experiments.ensembles missing
    python -m paper_lib.experiments.ensembles provenance  # records what existing scores were made from, checked first
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import pickle
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch as th
import yaml
from stable_baselines3.common.vec_env import VecNormalize

from paper_lib.agents.checkpoints import Checkpoint, load_checkpoint
from paper_lib.agents.envs import is_atari
from paper_lib.agents.factory import config_value
from paper_lib.agents.training import hp_flags, train_command
from paper_lib.common.io import atomic_dir, write_json_atomic, write_text_atomic
from paper_lib.common.provenance import file_digest
from paper_lib.methods.independent import assemble_ensemble
from paper_lib.methods.networks import MEMBER_METHODS
from paper_lib.ood.datasets import StateDataset
from paper_lib.pipeline.config import PARAMS_FILE, RunConfig, check_keys, parse_params, validate_params
from paper_lib.pipeline.landing import TRAINING_KEYS, differences, expected_for
from paper_lib.pipeline.layout import RUN_FOLDERS, combination_name
from paper_lib.pipeline.run_results import (CHECKPOINT_INPUTS, PROVENANCE_FILE, check_provenance,
                                            check_score_provenance, check_scores_destination, describe_identity,
                                            identity_error, provenance_record, provenance_to_record,
                                            provenance_to_write)
from paper_lib.pipeline.stages import collect_run, collect_states

SECTION = "ensembles"
ASSIGNMENTS = ("shared", "own")
#: What a run needs before it enters the tables, in pipeline order.
ARTIFACTS = tuple(RUN_FOLDERS)
#: How to fix a wrong `ensembles` section, said at the end of each error.
FIX = "see docs/ensembles.md"
#: The `method` of an assembled ensemble (its checkpoint config, its dataset's metadata, its scores' rows).
ENSEMBLE_METHOD = "independent_ensemble"
#: What a combination's scores folder holds: its metrics and what they were made from.
COMBINATION_SCORE_FILES = ("metrics.csv", PROVENANCE_FILE)
#: The command that records what existing ensembles scores were made from (`record_provenance`).
BACKFILL = "python -m paper_lib.experiments.ensembles provenance"


def _fail(path: Path, where: str, problem: str) -> ValueError:
    return ValueError(f"{path}: {SECTION}.{where}: {problem}; {FIX}")


def _int_list(value: Any, path: Path, where: str, minimum: int = 0) -> list[int]:
    if not isinstance(value, list) or not value or any(isinstance(v, bool) or not isinstance(v, int) or v < minimum
                                                        for v in value):
        raise _fail(path, where, f"must be a non-empty list of integers >= {minimum}, got {value!r}")
    if len(set(value)) != len(value):
        raise _fail(path, where, f"lists an entry twice: {value!r}")
    return list(value)


def _name_list(value: Any, known: list[str] | tuple[str, ...], path: Path, where: str) -> list[str]:
    if not isinstance(value, list) or not value:
        raise _fail(path, where, f"must be a non-empty list, got {value!r}")
    unknown = [v for v in value if v not in known]
    if unknown:
        raise _fail(path, where, f"unknown {unknown}; known: {sorted(known)}")
    if len(set(value)) != len(value):
        raise _fail(path, where, f"lists an entry twice: {value!r}")
    return list(value)


def combinations(member_seeds: list[int], size: int) -> list[tuple[int, ...]]:
    """Every `size`-of-n combination of the members, in the paper's order ({1,2,3,4}, {1,2,3,5}, ...)."""
    if size < 2 or size > len(member_seeds):
        raise ValueError(f"cannot form ensembles of {size} from {len(member_seeds)} members {member_seeds}; "
                         "use 2 <= ensemble_size <= the number of member seeds")
    return list(itertools.combinations(member_seeds, size))


@dataclass(frozen=True)
class EnsemblesConfig:
    """The `ensembles` section for the active profile, validated, with the paths of every run."""

    run: RunConfig
    budget_fraction: float
    epochs_factor: int
    ensemble_size: int
    envs: list[str]
    member_seeds: list[int]
    full_timesteps: int | None
    own_envs: list[str]
    own_methods: list[str]
    own_seeds: list[int]

    # --- the rule ---------------------------------------------------------------------------
    def member_budget(self, env_id: str) -> tuple[int, int]:
        """(training steps, n_epochs) of one independent member: a fraction of the steps, a multiple of the epochs."""
        hp = self.run.hyperparameters[env_id]
        full = self.full_timesteps or self.run.budget(env_id) or hp["total_timesteps"]
        epochs = (self.run.overrides or {}).get("n_epochs", hp["algo"]["n_epochs"])
        return max(1, round(self.budget_fraction * full)), self.epochs_factor * epochs

    def member_overrides(self, env_id: str) -> dict[str, Any]:
        return {**(self.run.overrides or {}), "n_epochs": self.member_budget(env_id)[1]}

    def combinations(self) -> list[tuple[int, ...]]:
        return combinations(self.member_seeds, self.ensemble_size)

    # --- the three results trees ----------------------------------------------------------------
    @property
    def independent(self) -> RunConfig:
        """The members' tree: results/<profile>/independent/, members are `baseline` runs."""
        return dataclasses.replace(self.run, profile=f"{self.run.profile}/independent", envs=self.envs,
                                   methods=["baseline"], seeds=self.member_seeds)

    @property
    def shared(self) -> RunConfig:
        """The shared twins: the main tree, restricted to the own-vs-shared matrix."""
        return dataclasses.replace(self.run, envs=self.own_envs, methods=self.own_methods, seeds=self.own_seeds)

    @property
    def own(self) -> RunConfig:
        """The own runs: results/<profile>/own/, laid out like the main tree."""
        return dataclasses.replace(self.shared, profile=f"{self.run.profile}/own")

    def tree(self, assignment: str) -> RunConfig:
        return self.own if assignment == "own" else self.shared

    def member_dir(self, env_id: str, seed: int) -> Path:
        return self.independent.checkpoint_dir(env_id, "baseline", seed)

    def combination_dataset(self, env_id: str, members: tuple[int, ...]) -> Path:
        return self.independent.layout.combination_dataset(env_id, members)

    def combination_evaluation(self, env_id: str, members: tuple[int, ...]) -> Path:
        return self.independent.layout.combination_evaluation(env_id, members)

    def combination_metrics(self, env_id: str, members: tuple[int, ...]) -> Path:
        return self.independent.layout.combination_metrics(env_id, members)

    def own_runs(self) -> list[tuple[str, str, int]]:
        return self.shared.runs()

    # --- captions -----------------------------------------------------------------------------
    def independent_caption(self) -> str:
        """The budget of the independent ensembles, for table captions."""
        steps = ", ".join(f"{e} {s:,} steps x {n} epochs" for e in self.envs for s, n in [self.member_budget(e)])
        return (f"profile '{self.run.profile}': members with seeds {self.member_seeds}, each trained alone with "
                f"{self.budget_fraction:g} of the steps and {self.epochs_factor}x the epochs ({steps}); "
                f"ensembles of {self.ensemble_size} from {len(self.combinations())} combinations; "
                f"{self.run.eval_episodes} evaluation episodes per combination; {self.run.protocol_caption()}")

    def own_caption(self) -> str:
        """The budget of the own-vs-shared comparison, for table captions."""
        steps = self.run.steps_caption()
        return (f"profile '{self.run.profile}': seeds {self.own_seeds}, {steps} training steps per run (the main "
                f"matrix's recipe and budget), {self.run.eval_episodes} evaluation episodes; "
                f"{self.run.protocol_caption()}")

    def describe(self) -> str:
        return f"independent ensembles ({self.independent_caption()}); own vs shared ({self.own_caption()})"


def load_ensembles_config(path: str | Path = PARAMS_FILE) -> EnsemblesConfig:
    """params.yaml's `ensembles` section for the active profile; every error names the file and the fix."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found; run from the repository root (it holds params.yaml)")
    params = parse_params(path.read_text(), path)  # one reader: syntax errors and duplicate keys named with their line
    section = params.pop(SECTION, None)
    # the rest of params.yaml gets the pipeline's own checks, as if this section were not there
    run = validate_params(parse_params(yaml.safe_dump(params), path), path)
    if not isinstance(section, dict):
        raise ValueError(f"{path} has no `{SECTION}` section (or it is not a mapping); add it, see docs/ensembles.md")
    check_keys(section, f"{path}: {SECTION}", ("rule", "profiles"), ("rule", "profiles"), fix=FIX)
    rule, profiles = section["rule"], section["profiles"]
    rule_keys = ("budget_fraction", "epochs_factor", "ensemble_size")
    check_keys(rule, f"{path}: {SECTION}.rule", rule_keys, rule_keys, fix=FIX)
    fraction = rule["budget_fraction"]
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0 < fraction <= 1:
        raise _fail(path, "rule.budget_fraction", f"must be a number in (0, 1], got {fraction!r}")
    for key, minimum in (("epochs_factor", 1), ("ensemble_size", 2)):
        value = rule[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise _fail(path, f"rule.{key}", f"must be an integer >= {minimum}, got {value!r}")
    if not isinstance(profiles, dict) or run.profile not in profiles:
        raise _fail(path, "profiles", f"has no entry for the active profile {run.profile!r}; add "
                                      f"`{run.profile}: {{independent: ..., own_vs_shared: ...}}`")
    entry, where = profiles[run.profile], f"profiles.{run.profile}"
    parts = ("independent", "own_vs_shared")
    check_keys(entry, f"{path}: {SECTION}.{where}", parts, parts, fix=FIX)
    ind, ovs, hps = entry["independent"], entry["own_vs_shared"], run.hyperparameters
    for name, value, keys in (("independent", ind, ("envs", "member_seeds", "total_timesteps")),
                              ("own_vs_shared", ovs, ("envs", "methods", "seeds"))):
        check_keys(value, f"{path}: {SECTION}.{where}.{name}", keys, keys, fix=FIX)
    full = ind["total_timesteps"]
    if full is not None and (isinstance(full, bool) or not isinstance(full, int) or full < 1):
        raise _fail(path, f"{where}.independent.total_timesteps", f"must be null or a positive integer, got {full!r}")
    seeds = _int_list(ind["member_seeds"], path, f"{where}.independent.member_seeds")
    if len(seeds) < rule["ensemble_size"]:
        raise _fail(path, f"{where}.independent.member_seeds",
                    f"{len(seeds)} members cannot form ensembles of {rule['ensemble_size']}; list more seeds")
    return EnsemblesConfig(
        run=run, budget_fraction=float(fraction), epochs_factor=rule["epochs_factor"],
        ensemble_size=rule["ensemble_size"], envs=_name_list(ind["envs"], list(hps), path, f"{where}.independent.envs"),
        member_seeds=seeds, full_timesteps=full,
        own_envs=_name_list(ovs["envs"], [e for e in hps if not is_atari(e)], path, f"{where}.own_vs_shared.envs"),
        own_methods=_name_list(ovs["methods"], MEMBER_METHODS, path, f"{where}.own_vs_shared.methods"),
        own_seeds=_int_list(ovs["seeds"], path, f"{where}.own_vs_shared.seeds"),
    )


# ------------------------------------------------------------------------------------ training


def member_train_args(cfg: EnsemblesConfig, env_id: str) -> tuple[int, dict[str, Any]]:
    """(total_timesteps, agent_kwargs) of an independent member: paper_lib.agents.training.train_run's arguments."""
    steps, _ = cfg.member_budget(env_id)
    return steps, {"hyperparameters": cfg.run.hyperparameters[env_id], "overrides": cfg.member_overrides(env_id),
                   "inference": cfg.run.inference}


def own_train_args(cfg: EnsemblesConfig, env_id: str) -> tuple[int | None, dict[str, Any]]:
    """(total_timesteps, agent_kwargs) of an `own` run: the main matrix's recipe and budget, assignment own."""
    return cfg.run.budget(env_id), {"hyperparameters": cfg.run.hyperparameters[env_id],
                                     "overrides": cfg.run.overrides or None, "inference": cfg.run.inference,
                                     "assignment": "own"}


def train_member(cfg: EnsemblesConfig, env_id: str, seed: int, **train_kwargs: Any) -> Path:
    from paper_lib.agents.training import train_run

    steps, kwargs = member_train_args(cfg, env_id)
    return train_run(env_id, "baseline", seed, cfg.member_dir(env_id, seed), total_timesteps=steps,
                     agent_kwargs=kwargs, **train_kwargs)


def train_own(cfg: EnsemblesConfig, env_id: str, method: str, seed: int, **train_kwargs: Any) -> Path:
    from paper_lib.agents.training import train_run

    steps, kwargs = own_train_args(cfg, env_id)
    return train_run(env_id, method, seed, cfg.own.checkpoint_dir(env_id, method, seed), total_timesteps=steps,
                     agent_kwargs=kwargs, **train_kwargs)


def member_command(cfg: EnsemblesConfig, env_id: str, seed: int, resume_root: str | None = None,
                   python: str = ".venv/bin/python") -> str:
    """The `python -m paper_lib.agents.training` line that trains one member exactly as `train_member` does."""
    steps, _ = cfg.member_budget(env_id)
    return train_command([env_id, "baseline", str(seed), str(cfg.member_dir(env_id, seed)), f"--timesteps {steps}",
                        *hp_flags(cfg.member_overrides(env_id))], resume_root, python)


def run_command(cfg: EnsemblesConfig, assignment: str, env_id: str, method: str, seed: int,
                resume_root: str | None = None, python: str = ".venv/bin/python") -> str:
    """The training line of an `own` run, or of a missing `shared` twin as the main matrix trains it."""
    args = [env_id, method, str(seed), str(cfg.tree(assignment).checkpoint_dir(env_id, method, seed))]
    if cfg.run.budget(env_id) is not None:
        args.append(f"--timesteps {cfg.run.budget(env_id)}")
    if assignment == "own":
        args.append("--assignment own")
    return train_command(args + hp_flags(cfg.run.overrides or {}), resume_root, python)


# --------------------------------------------------------------------------------- what exists


def read_config(folder: Path) -> dict[str, Any] | None:
    """A checkpoint folder's config.json, or None where the run is not (completely) trained."""
    try:
        return json.loads((folder / "config.json").read_text()) if (folder / "model.zip").is_file() else None
    except (OSError, json.JSONDecodeError):
        return None


def member_problem(cfg: EnsemblesConfig, env_id: str, seed: int) -> str | None:
    """Why member (env, seed) cannot be used yet, or None: not trained, or not as the rule trains it."""
    config = read_config(cfg.member_dir(env_id, seed))
    if config is None:
        return "not trained"
    steps, kwargs = member_train_args(cfg, env_id)
    wrong = differences(config, expected_for(env_id, "baseline", seed, steps, kwargs))
    return f"not trained as the rule trains it ({'; '.join(wrong)}); retrain it" if wrong else None


def own_problem(cfg: EnsemblesConfig, env_id: str, method: str, seed: int) -> str | None:
    """Why the own run (env, method, seed) is not trained as the profile says, or None."""
    config = read_config(cfg.own.checkpoint_dir(env_id, method, seed))
    if config is None:
        return "not trained"
    steps, kwargs = own_train_args(cfg, env_id)
    wrong = differences(config, expected_for(env_id, method, seed, steps, kwargs))
    if config.get("assignment") != "own":
        wrong.insert(0, f"assignment: trained with {config.get('assignment')!r}, the part needs 'own'")
    return f"trained with other settings ({'; '.join(wrong)}); retrain it" if wrong else None


def pair_problem(shared: dict[str, Any] | None, own: dict[str, Any] | None) -> str | None:
    """Why a shared run and its own twin cannot be compared, or None."""
    if shared is None or own is None:
        return " and ".join(name for name, c in (("shared", shared), ("own", own)) if c is None) + " not trained"
    if shared.get("assignment", "shared") != "shared" or own.get("assignment") != "own":
        return f"assignments are {shared.get('assignment')!r} / {own.get('assignment')!r}"
    # the training settings (paper_lib.pipeline.landing.TRAINING_KEYS) must agree, all but the assignment
    differ = [k for k in TRAINING_KEYS if config_value(shared, k) != config_value(own, k)]
    if differ:
        return "trained with different settings: " + "; ".join(f"{k}: shared {shared.get(k)!r}, own {own.get(k)!r}"
                                                               for k in differ)
    return None


def run_has(tree: RunConfig, run: tuple[str, str, int], artifact: str) -> bool:
    """Whether a run of `tree` (the main tree or a mirror) has `artifact` (one of ARTIFACTS)."""
    from paper_lib.pipeline.status import has

    return has(tree, run, artifact)


def combination_has(cfg: EnsemblesConfig, env_id: str, members: tuple[int, ...], artifact: str) -> bool:
    if artifact == "checkpoint":
        return all(member_problem(cfg, env_id, s) is None for s in members)
    path = {"dataset": cfg.combination_dataset, "evaluation": cfg.combination_evaluation,
            "scores": cfg.combination_metrics}[artifact](env_id, members)
    return path.is_file()


def complete_pairs(cfg: EnsemblesConfig) -> list[tuple[str, str, int]]:
    """The own-vs-shared runs whose two twins have every artifact and were trained alike."""
    return [run for run in cfg.own_runs()
            if all(run_has(cfg.tree(a), run, art) for a in ASSIGNMENTS for art in ARTIFACTS)
            and pair_problem(*(read_config(cfg.tree(a).checkpoint_dir(*run)) for a in ASSIGNMENTS)) is None]


def complete_combinations(cfg: EnsemblesConfig) -> list[tuple[str, int, tuple[int, ...]]]:
    """(env, index, members) of every combination with all its members, states, episodes and scores."""
    return [(e, c, m) for e in cfg.envs for c, m in enumerate(cfg.combinations())
            if all(combination_has(cfg, e, m, art) for art in ARTIFACTS)]


def _shared_fix(cfg: EnsemblesConfig, run: tuple[str, str, int], artifact: str) -> str:
    in_main = run in cfg.run.runs()
    stage = {"dataset": "collect", "evaluation": "evaluate", "scores": "score"}[artifact]
    if in_main:
        return f"dvc repro -s {stage}@{run[0]}-{run[1]}-{run[2]}"
    return f"python -m paper_lib.experiments.ensembles {'collect' if artifact == 'dataset' else 'evaluate'}"


def missing_runs(cfg: EnsemblesConfig) -> pd.DataFrame:
    """Every run, dataset, evaluation or score the tables need and do not have yet, why, and the fix."""
    rows = []

    def add(part, env_id, method, seed, who, artifact, path, problem, fix):
        rows.append(dict(part=part, env=env_id, method=method, seed=seed, run=who, artifact=artifact, path=str(path),
                         problem=problem, fix=fix))

    for env_id in cfg.envs:
        for seed in cfg.member_seeds:
            if problem := member_problem(cfg, env_id, seed):
                add("independent", env_id, "baseline", seed, "member", "checkpoint", cfg.member_dir(env_id, seed),
                    problem, member_command(cfg, env_id, seed))
        for members in cfg.combinations():
            if not combination_has(cfg, env_id, members, "checkpoint"):
                continue
            for artifact, path in (("dataset", cfg.combination_dataset(env_id, members)),
                                   ("evaluation", cfg.combination_evaluation(env_id, members)),
                                   ("scores", cfg.combination_metrics(env_id, members))):
                if not path.is_file():
                    command = "collect" if artifact == "dataset" else "evaluate"
                    add("independent", env_id, "baseline", None, combination_name(members), artifact, path,
                        "missing", f"python -m paper_lib.experiments.ensembles {command}")
    for run in cfg.own_runs():
        env_id, method, seed = run
        for assignment in ASSIGNMENTS:
            tree = cfg.tree(assignment)
            for artifact in ARTIFACTS:
                if run_has(tree, run, artifact) and not (artifact == "checkpoint" and assignment == "own"
                                                         and own_problem(cfg, *run)):
                    continue
                path = tree.layout.run_path(artifact, *run)
                if artifact == "checkpoint":
                    fix = run_command(cfg, assignment, *run)
                elif assignment == "shared":
                    fix = _shared_fix(cfg, run, artifact)
                else:
                    fix = f"python -m paper_lib.experiments.ensembles {'collect' if artifact == 'dataset' else 'evaluate'}"
                problem = "missing" if artifact != "checkpoint" else (
                    own_problem(cfg, *run) if assignment == "own" else "not trained")
                add("own_vs_shared", env_id, method, seed, assignment, artifact, path, problem, fix)
                break  # the later artifacts follow from this one
        configs = [read_config(cfg.tree(a).checkpoint_dir(*run)) for a in ASSIGNMENTS]
        if None not in configs and (problem := pair_problem(*configs)):
            add("own_vs_shared", env_id, method, seed, "pair", "checkpoint", cfg.own.checkpoint_dir(*run), problem,
                "retrain the older run with the current recipe")
    columns = ["part", "env", "method", "seed", "run", "artifact", "path", "problem", "fix"]
    return pd.DataFrame(rows, columns=columns).astype({"seed": "Int64"})  # no seed where a row is a combination


def queue_lines(cfg: EnsemblesConfig, resume_root: str | None = None, python: str = ".venv/bin/python") -> list[str]:
    """One training command per run that is missing (or, for a member, trained with other settings)."""
    lines = []
    for row in missing_runs(cfg).itertuples():
        if row.run == "member":
            lines.append(member_command(cfg, row.env, int(row.seed), resume_root, python))
        elif row.run in ASSIGNMENTS and row.artifact == "checkpoint":
            lines.append(run_command(cfg, row.run, row.env, row.method, int(row.seed), resume_root, python))
    return lines


# ---------------------------------------------------------------------------- assembled ensembles


def assemble_members(cfg: EnsemblesConfig, env_id: str, members: tuple[int, ...]) -> Checkpoint:
    """The members' checkpoints as one ensemble (no retraining), wrapped like a checkpoint for evaluation.

    The ensemble takes raw observations (each member applies its own normalizer), so the
    checkpoint has no normalizer of its own: `Checkpoint.env` is the plain env.
    """
    checkpoints = [load_checkpoint(cfg.member_dir(env_id, s), env_id, "baseline", s) for s in members]
    normalizers = [_read_normalizer(c.vecnormalize_path) if c.vecnormalize_path is not None else None
                   for c in checkpoints]
    config = dict(algo="ppo", method=ENSEMBLE_METHOD, env_id=env_id, member_seeds=list(members),
                  n_members=len(members), inference=cfg.run.inference, normalize_obs=False,
                  members_normalize_obs=any(n is not None for n in normalizers),
                  member_folders=[str(c.folder) for c in checkpoints])
    model = assemble_ensemble([c.model for c in checkpoints], normalizers, inference=cfg.run.inference,
                              member_seeds=list(members), config=config)
    return Checkpoint(model, config, None, cfg.member_dir(env_id, members[0]).parent)


def _read_normalizer(path: Path) -> VecNormalize:
    with open(path, "rb") as f:  # a pickled VecNormalize (no env attached), as train.py saves it
        return pickle.load(f)


# ---------------------------------------------------------------------- states, episodes, scores


def evaluate_agent(run: RunConfig, checkpoint: Checkpoint, seed: int) -> pd.DataFrame:
    """Evaluation episodes (combined and single inference, both action modes), seeded as `run_results.evaluate_run`."""
    from paper_lib.scoring.rewards import evaluate_rewards

    th.set_num_threads(1)
    th.manual_seed(10_000 + seed)
    return evaluate_rewards(checkpoint, run.eval_episodes, seed=10_000 + seed)


def score_agent(run: RunConfig, checkpoint: Checkpoint, dataset: StateDataset, seed: int) -> pd.DataFrame:
    """OOD metrics of every measure and detector, seeded like `run_results.score_run_files`."""
    from paper_lib.scoring.ood_scores import score_run

    th.set_num_threads(1)
    th.manual_seed(seed)
    return score_run(checkpoint, dataset, np.random.default_rng(seed), run.n_bootstrap).metrics


def _csv(df: pd.DataFrame) -> str:
    return df.to_csv(index=False, lineterminator="\n")


def collect_all(cfg: EnsemblesConfig, log=print) -> list[Path]:
    """States of every trained combination and own run without them (and of shared twins outside the main matrix).

    Combination c (in `cfg.combinations()` order) collects with seed c, through the main pipeline's
    `collect_states` (the same calls and OOD source as every run of the tables); a run with its own seed.
    """
    _make_dirs(cfg, "dataset")
    written = []
    for env_id in cfg.envs:
        for c, members in enumerate(cfg.combinations()):
            path = cfg.combination_dataset(env_id, members)
            if combination_has(cfg, env_id, members, "checkpoint") and not path.is_file():
                ensemble = assemble_members(cfg, env_id, members)
                written.append(collect_states(cfg.run, ensemble.model, env_id, c).save(path))
                log(f"collected {path}")
    for tree, run in _runs_to_do(cfg, "dataset"):
        written.append(collect_run(tree, *run))
        log(f"collected {written[-1]}")
    return written


def evaluate_all(cfg: EnsemblesConfig, log=print) -> list[Path]:
    """Reward episodes and OOD metrics of every combination and own run that has states but not these yet."""
    from paper_lib.pipeline.run_results import evaluate_run, score_run_files

    _make_dirs(cfg, "evaluation", "scores")
    written = []
    for env_id in cfg.envs:
        for c, members in enumerate(cfg.combinations()):
            if not combination_has(cfg, env_id, members, "dataset") or not combination_has(cfg, env_id, members,
                                                                                             "checkpoint"):
                continue
            todo = [p for p in (cfg.combination_evaluation(env_id, members), cfg.combination_metrics(env_id, members))
                    if not p.is_file()]
            if not todo:
                continue
            if not cfg.combination_metrics(env_id, members).is_file():  # before any work
                check_scores_destination(combination_scores_dir(cfg, env_id, members), env_id, COMBINATION_SCORE_FILES)
            ensemble = assemble_members(cfg, env_id, members)
            if not cfg.combination_evaluation(env_id, members).is_file():
                episodes = evaluate_agent(cfg.run, ensemble, c).assign(**_combination_tag(env_id, c, members))
                written.append(write_text_atomic(cfg.combination_evaluation(env_id, members), _csv(episodes)))
            if not cfg.combination_metrics(env_id, members).is_file():
                written.append(score_combination(cfg, env_id, c, members, ensemble))
            log(f"evaluated {env_id} {combination_name(members)}")
    for tree, run in _runs_to_do(cfg, "evaluation"):
        written.append(evaluate_run(tree, *run))
        log(f"evaluated {written[-1]}")
    for tree, run in _runs_to_do(cfg, "scores"):
        written.append(score_run_files(tree, *run))
        log(f"scored {written[-1]}")
    return written


def _combination_tag(env_id: str, c: int, members: tuple[int, ...]) -> dict[str, Any]:
    """The columns naming a combination in its evaluation and metrics rows."""
    return dict(env=env_id, method=ENSEMBLE_METHOD, combination=c, members=combination_name(members))


def score_combination(cfg: EnsemblesConfig, env_id: str, c: int, members: tuple[int, ...],
                      ensemble: Checkpoint | None = None) -> Path:
    """OOD metrics of combination c (members `members`) from its dataset, written with their provenance at once
    (`combination_provenance`, of the files as they are when scoring starts); returns the metrics file.

    A folder at the scores path holding files but none of a combination's is refused before any work, as the main
    score stage does; a dataset collected by another combination is refused before scoring.
    """
    out = check_scores_destination(combination_scores_dir(cfg, env_id, members), env_id, COMBINATION_SCORE_FILES)
    provenance = combination_provenance(cfg, env_id, members)
    path = cfg.combination_dataset(env_id, members)
    data = StateDataset.load(path)
    check_combination_dataset(data.metadata, path, env_id, c, members)
    ensemble = ensemble or assemble_members(cfg, env_id, members)
    metrics = score_agent(cfg.run, ensemble, data, c).assign(**_combination_tag(env_id, c, members))
    with atomic_dir(out) as tmp:
        (tmp / "metrics.csv").write_text(_csv(metrics))
        write_json_atomic(tmp / PROVENANCE_FILE, provenance)
    return out / "metrics.csv"


# ------------------------------------------------------------------ provenance: scores <- their inputs
# The main matrix's record (paper_lib.pipeline.run_results), with an assembled ensemble's identity: the env, the method
# and the members (no seed), and one SHA-256 per member checkpoint file, named `seed<s>/model.zip` (the member's
# folder under checkpoints/<env>/baseline/). An `own` run is a run of the own tree: the main matrix's record as is.


def combination_scores_dir(cfg: EnsemblesConfig, env_id: str, members: tuple[int, ...]) -> Path:
    return cfg.combination_metrics(env_id, members).parent


def combination_identity(env_id: str, members: tuple[int, ...]) -> dict[str, Any]:
    return {"env": env_id, "method": ENSEMBLE_METHOD, "members": list(members)}


def combination_inputs(cfg: EnsemblesConfig, env_id: str, members: tuple[int, ...]) -> dict[str, Path]:
    """The files a combination's scores are made from: its dataset and each member's model.zip and normalizer."""
    return {"dataset": cfg.combination_dataset(env_id, members),
            **{f"seed{s}/{name}": cfg.member_dir(env_id, s) / name for s in members for name in CHECKPOINT_INPUTS}}


def combination_provenance(cfg: EnsemblesConfig, env_id: str, members: tuple[int, ...]) -> dict[str, Any]:
    """What a combination's scores are made from, as its `provenance.json` holds it."""
    return provenance_record(combination_identity(env_id, members), combination_inputs(cfg, env_id, members))


def _rescore(folder: Path) -> str:
    """How to make ensembles scores again: `evaluate` scores what has no metrics.csv."""
    return f"score them again (move {folder} away, then `python -m paper_lib.experiments.ensembles evaluate`)"


def check_combination_provenance(cfg: EnsemblesConfig, env_id: str, members: tuple[int, ...]) -> None:
    """A combination's scores must carry their record, naming this combination and its current dataset and members'
    files; one ValueError naming both sides otherwise, or the backfill command where the record is missing."""
    folder = combination_scores_dir(cfg, env_id, members)
    check_provenance(folder, combination_identity(env_id, members), combination_inputs(cfg, env_id, members),
                     _rescore(folder), BACKFILL, required=True)


def check_own_provenance(cfg: EnsemblesConfig, env_id: str, method: str, seed: int) -> None:
    """An `own` run's scores must carry their record (the main matrix's), naming the run and its current files."""
    check_score_provenance(cfg.own, env_id, method, seed, required=True,
                           rescore=_rescore(cfg.own.layout.scores_dir(env_id, method, seed)), backfill=BACKFILL)


def check_combination_dataset(metadata: dict[str, Any], path: Path, env_id: str, c: int,
                              members: tuple[int, ...]) -> None:
    """The dataset at a combination's path must be one collected by an assembled ensemble of as many members in that
    env, with combination c's seed (`collect_all`: `collect_states` seeds the ID states with 1000 c + 1); its metadata
    holds no member seeds, so the seed tells the combinations apart."""
    model = metadata.get("model") or {}
    ids = [p for p in metadata.get("parts") or [metadata] if p.get("kind") == "id"]
    found = (model.get("env_id", metadata.get("env_id")), model.get("method"), model.get("n_members"),
             ids[0].get("seed") if ids else None)
    wanted = (env_id, ENSEMBLE_METHOD, len(members), 1000 * c + 1)
    if found != wanted:
        raise ValueError(f"{path} was collected by {found[0]} {found[1]} of {found[2]} members with ID seed "
                         f"{found[3]}, not by {env_id} {combination_name(members)} (combination {c}: {len(members)} "
                         f"members, ID seed {wanted[3]}) whose path it sits at; put back its own dataset (`python -m "
                         "paper_lib.experiments.ensembles collect` collects a missing one)")


def _combination_record(cfg: EnsemblesConfig, env_id: str, c: int, members: tuple[int, ...]) -> dict[str, Any] | None:
    """The record `record_provenance` writes for a combination (None: already there), after every check on it: its
    metrics name it, each member is trained as the rule says, its inputs are present, its dataset is its own."""
    identity, folder = combination_identity(env_id, members), combination_scores_dir(cfg, env_id, members)
    path = folder / "metrics.csv"
    metrics = pd.read_csv(path)
    tag = _combination_tag(env_id, c, members)
    named = {k: ", ".join(map(str, sorted(set(metrics[k]), key=str))) if k in metrics else None for k in tag}
    if any(named[k] != str(v) for k, v in tag.items()):
        found = {"env": named["env"], "method": named["method"],
                 "members": f"{named['members']} (combination {named['combination']})"}
        raise identity_error(path, found, identity)
    for seed in members:
        if problem := member_problem(cfg, env_id, seed):
            raise ValueError(f"member {cfg.member_dir(env_id, seed)} of {describe_identity(identity)}: {problem}; its "
                             "scores are not recorded as made from it")
    inputs = combination_inputs(cfg, env_id, members)
    record = provenance_record(identity, inputs)  # a missing input: one error naming it
    with np.load(inputs["dataset"], allow_pickle=False) as data:
        check_combination_dataset(json.loads(str(data["metadata"])), inputs["dataset"], env_id, c, members)
    return provenance_to_write(folder, record, inputs, _rescore(folder), BACKFILL)


def _own_record(cfg: EnsemblesConfig, env_id: str, method: str, seed: int) -> dict[str, Any] | None:
    """The record of an `own` run's scores (None: already there), after the main matrix's checks and two of its own:
    the checkpoint is trained with `assignment="own"`, and no input or metrics file is a copy of the shared twin's (a
    run's metadata does not hold its assignment, so only the bytes tell the twins' files apart)."""
    if problem := own_problem(cfg, env_id, method, seed):
        raise ValueError(f"{cfg.own.checkpoint_dir(env_id, method, seed)}: {problem}; its scores are not recorded as "
                         "made from it")
    twins = [(tree.dataset_path(env_id, method, seed), tree.checkpoint_dir(env_id, method, seed) / CHECKPOINT_INPUTS[0],
              tree.layout.scores_dir(env_id, method, seed) / "metrics.csv") for tree in (cfg.own, cfg.shared)]
    for own, shared in zip(*twins):
        if own.is_file() and shared.is_file() and file_digest(own) == file_digest(shared):
            raise ValueError(f"{own} has the same bytes as the shared twin's {shared}: a file of the other run is "
                             "never recorded as the own run's; put back the own run's file")
    folder = cfg.own.layout.scores_dir(env_id, method, seed)
    return provenance_to_record(cfg.own, env_id, method, seed, rescore=_rescore(folder), backfill=BACKFILL)


def record_provenance(cfg: EnsemblesConfig) -> tuple[list[Path], int]:
    """Write `provenance.json` into every scored combination's and own run's folder that has none, from the current
    files: (the records written, the number of scored folders).

    As the main matrix's backfill (`run_results.record_provenance`): for committed scores whose inputs have not changed
    since they were scored; nothing is rescored. Every folder is checked before any file is written (its metrics name
    it, its dataset is its own, its members or checkpoint are the ones the profile says, no input is missing, a record
    there already names the same files): one error, and nothing is written. Records already there are left as they are.
    """
    records = []
    for env_id in cfg.envs:
        for c, members in enumerate(cfg.combinations()):
            folder = combination_scores_dir(cfg, env_id, members)
            if (folder / "metrics.csv").is_file():
                records.append((folder, _combination_record(cfg, env_id, c, members)))
    for run in cfg.own_runs():
        folder = cfg.own.layout.scores_dir(*run)
        if (folder / "metrics.csv").is_file():
            records.append((folder, _own_record(cfg, *run)))
    written = [write_json_atomic(folder / PROVENANCE_FILE, record) for folder, record in records if record is not None]
    return written, len(records)


def _make_dirs(cfg: EnsemblesConfig, *artifacts: str) -> None:
    """The folders a pipeline stage declares as outputs exist even while no run has reached them."""
    for tree in (cfg.independent, cfg.own):
        for artifact in artifacts:
            tree.layout.folder(artifact).mkdir(parents=True, exist_ok=True)


def _runs_to_do(cfg: EnsemblesConfig, artifact: str) -> list[tuple[RunConfig, tuple[str, str, int]]]:
    """Own runs, and shared twins the main matrix does not hold, that have what `artifact` needs but not it."""
    needs = {"dataset": ("checkpoint",), "evaluation": ("checkpoint",), "scores": ("checkpoint", "dataset")}[artifact]
    todo = []
    for run in cfg.own_runs():
        for assignment in ASSIGNMENTS:
            tree = cfg.tree(assignment)
            if assignment == "shared" and run in cfg.run.runs():
                continue  # the main pipeline's stages make these
            if all(run_has(tree, run, n) for n in needs) and not run_has(tree, run, artifact):
                todo.append((tree, run))
    return todo


# ------------------------------------------------------------------------------------------ CLI


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--params", default=str(PARAMS_FILE))
    sub = parser.add_subparsers(dest="command", required=True)
    train = sub.add_parser("train", help="train the runs of one part (all of it, or the ones selected)")
    train.add_argument("part", choices=("independent", "own"))
    train.add_argument("--env", action="append", help="only this env (repeatable)")
    train.add_argument("--method", action="append", help="only this method (own runs; repeatable)")
    train.add_argument("--seed", action="append", type=int, help="only this seed (repeatable)")
    train.add_argument("--threads", type=int, default=1, help="torch threads")
    train.add_argument("--force", action="store_true", help="retrain runs whose checkpoint is already up to date")
    sub.add_parser("collect", help="collect the ID/OOD states of every trained combination and run that lacks them")
    sub.add_parser("evaluate", help="reward episodes and OOD scores of every combination and run that lacks them")
    queue = sub.add_parser("queue", help="print the training commands of the runs still missing")
    queue.add_argument("--resume-root", default=None, help="prefix each line with env PAPER_LIB_RESUME_ROOT=DIR")
    queue.add_argument("--python", default=".venv/bin/python")
    sub.add_parser("missing", help="list what the tables still lack")
    sub.add_parser("provenance", help="record what the existing scores of every combination and own run were made "
                                      "from (each checked first; nothing is rescored)")
    args = parser.parse_args(argv)
    try:
        cfg = load_ensembles_config(args.params)
        if args.command == "train":
            if args.threads < 1:
                raise ValueError(f"--threads must be a positive number of torch threads, got {args.threads}")
            _train(cfg, args)
        elif args.command == "collect":
            collect_all(cfg)
        elif args.command == "evaluate":
            evaluate_all(cfg)
        elif args.command == "provenance":
            written, scored = record_provenance(cfg)
            print(f"{len(written)} provenance record(s) written, {scored - len(written)} already there "
                  f"({scored} scored combinations and own runs of profile {cfg.run.profile!r})")
        elif args.command == "queue":
            for line in queue_lines(cfg, args.resume_root, args.python):
                print(line)
        else:
            with pd.option_context("display.max_colwidth", 80, "display.width", 200):
                print(missing_runs(cfg).drop(columns="fix").to_string(index=False))
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")


def _train(cfg: EnsemblesConfig, args: argparse.Namespace) -> None:
    def chosen(values: list[Any], picked: list[Any] | None, what: str) -> list[Any]:
        unknown = sorted(set(picked or []) - set(values), key=str)
        if unknown:
            raise ValueError(f"{what} {unknown} is not in this profile's {what}s {values}; pick from those")
        return [v for v in values if picked is None or v in picked]

    if args.part == "independent":
        if args.method:
            raise ValueError("--method only applies to `train own`; independent members are baseline agents")
        for env_id in chosen(cfg.envs, args.env, "env"):
            for seed in chosen(cfg.member_seeds, args.seed, "seed"):
                if args.force or member_problem(cfg, env_id, seed):
                    print(train_member(cfg, env_id, seed, torch_threads=args.threads), file=sys.stderr)
        return
    for env_id in chosen(cfg.own_envs, args.env, "env"):
        for method in chosen(cfg.own_methods, args.method, "method"):
            for seed in chosen(cfg.own_seeds, args.seed, "seed"):
                if args.force or own_problem(cfg, env_id, method, seed):
                    print(train_own(cfg, env_id, method, seed, torch_threads=args.threads), file=sys.stderr)


if __name__ == "__main__":
    main()
