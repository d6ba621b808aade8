"""params.yaml -> a validated run configuration. Every pipeline input error is raised here.

params.yaml has three parts: `profiles` (named budgets: tiny, cpu, paper), `run` (a copy of
the active profile, which dvc.yaml's stage matrices read), and `hyperparameters` (the
paper's per-environment settings). Switch profile with

    python -m paper_lib.config use tiny
"""

from __future__ import annotations

import argparse
import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from paper_lib.methods.networks import METHODS

PARAMS_FILE = Path("params.yaml")
HEADER = """\
# Pipeline parameters. `run` is the active profile (read by dvc.yaml); switch with
#   python -m paper_lib.config use <profile>
# `hyperparameters` are the paper's (appendix B), keyed by Gymnasium id.
"""


class _PlainDumper(yaml.SafeDumper):
    """Writes repeated values out in full: params.yaml is read by people, not only by code."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


@dataclass(frozen=True)
class RunConfig:
    """The active profile, validated."""

    profile: str
    envs: list[str]
    methods: list[str]
    seeds: list[int]
    total_timesteps: int | None
    overrides: dict[str, Any]
    n_id_states: int
    n_ood_states: int
    eval_episodes: int
    max_episode_steps: int
    skip_first: int
    deterministic: bool
    inference: str
    n_bootstrap: int
    hyperparameters: dict[str, dict[str, Any]] = field(repr=False)
    root: Path = Path(".")

    @property
    def results(self) -> Path:
        return self.root / "results" / self.profile

    def checkpoint_dir(self, env_id: str, method: str, seed: int) -> Path:
        return self.results / "checkpoints" / env_id / method / f"seed{seed}"

    def dataset_path(self, env_id: str, method: str, seed: int) -> Path:
        return self.results / "datasets" / env_id / method / f"seed{seed}.npz"

    @property
    def tables(self) -> Path:
        return self.results / "tables"

    @property
    def figures(self) -> Path:
        return self.results / "figures"

    def runs(self) -> list[tuple[str, str, int]]:
        return [(e, m, s) for e in self.envs for m in self.methods for s in self.seeds]

    def budget_caption(self) -> str:
        steps = self.total_timesteps or "the paper's"
        return (f"profile '{self.profile}': {len(self.seeds)} seed(s) {self.seeds}, {steps} training steps per run, "
                f"{self.eval_episodes} evaluation episodes; the paper used 3 seeds")


REQUIRED = ("envs", "methods", "seeds", "total_timesteps", "overrides", "n_id_states", "n_ood_states",
            "eval_episodes", "max_episode_steps", "skip_first", "deterministic", "inference", "n_bootstrap")


def read_params(path: str | Path = PARAMS_FILE) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found; run from the repository root (it holds params.yaml)")
    params = yaml.safe_load(path.read_text())
    if not isinstance(params, dict) or not {"run", "profiles", "hyperparameters"} <= set(params):
        raise ValueError(f"{path} must have the sections 'profiles', 'run' and 'hyperparameters'; "
                         "restore it with `git checkout params.yaml`")
    return params


def load_run_config(path: str | Path = PARAMS_FILE) -> RunConfig:
    """The active profile from params.yaml, with every name checked."""
    path = Path(path)
    params = read_params(path)
    run, hps = params["run"], params["hyperparameters"]
    profile = run.get("profile")
    if profile not in params["profiles"]:
        raise ValueError(f"{path}: unknown profile {profile!r} in `run`; known: {sorted(params['profiles'])}. "
                         "Fix with `python -m paper_lib.config use <profile>`")
    missing = [k for k in REQUIRED if k not in run]
    if missing:
        raise ValueError(f"{path}: `run` lacks {missing}; regenerate it with `python -m paper_lib.config use {profile}`")
    for env_id in run["envs"]:
        if env_id not in hps:
            raise ValueError(f"{path}: unknown env {env_id!r} in profile {profile!r}; "
                             f"params.yaml has hyperparameters for {sorted(hps)}")
    for method in run["methods"]:
        if method not in METHODS:
            raise ValueError(f"{path}: unknown method {method!r} in profile {profile!r}; use one of {METHODS}")
    if not run["seeds"] or not all(isinstance(s, int) for s in run["seeds"]):
        raise ValueError(f"{path}: seeds must be a non-empty list of integers, got {run['seeds']!r}")
    for key in ("n_id_states", "n_ood_states", "eval_episodes", "max_episode_steps", "n_bootstrap"):
        if not isinstance(run[key], int) or run[key] <= 0:
            raise ValueError(f"{path}: {key} must be a positive integer, got {run[key]!r}")
    return RunConfig(profile=profile, **{k: run[k] for k in REQUIRED}, hyperparameters=hps, root=path.parent)


def use_profile(name: str, path: str | Path = PARAMS_FILE) -> None:
    """Make profile `name` the active one (rewrites the `run` section)."""
    path = Path(path)
    params = read_params(path)
    if name not in params["profiles"]:
        raise ValueError(f"unknown profile {name!r}; known: {sorted(params['profiles'])}")
    params["run"] = {"profile": name, **copy.deepcopy(params["profiles"][name])}
    ordered = {"run": params["run"], "profiles": params["profiles"], "hyperparameters": params["hyperparameters"]}
    path.write_text(HEADER + yaml.dump(ordered, Dumper=_PlainDumper, sort_keys=False, default_flow_style=None, width=110))
    load_run_config(path)


def main() -> None:
    parser = argparse.ArgumentParser(description="Switch the pipeline's budget profile.")
    sub = parser.add_subparsers(dest="command", required=True)
    use = sub.add_parser("use", help="make a profile active")
    use.add_argument("profile")
    sub.add_parser("show", help="print the active profile")
    args = parser.parse_args()
    if args.command == "use":
        use_profile(args.profile)
    print(load_run_config())


if __name__ == "__main__":
    main()
