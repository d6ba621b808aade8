"""params.yaml -> a validated run configuration. Every pipeline input error is raised here.

params.yaml has three parts: `profiles` (named budgets: tiny, cpu, paper), `run` (a copy of
the active profile, which dvc.yaml's stage matrices read), and `hyperparameters` (the
paper's per-environment settings). Switch profile with

    python -m paper_lib.pipeline.config use tiny
"""

from __future__ import annotations

import argparse
import copy
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from paper_lib.agents.factory import check_algo_settings, check_integer, check_seed, validate_hyperparameters
from paper_lib.common.checks import check_keys
from paper_lib.common.io import write_text_atomic
from paper_lib.methods.groups import check_member_layout
from paper_lib.methods.networks import METHODS
from paper_lib.methods.policy import INFERENCE_MODES
from paper_lib.pipeline.layout import Layout, results_dir

PARAMS_FILE = Path("params.yaml")
HEADER = """\
# Pipeline parameters. `run` is the active profile (read by dvc.yaml); switch with
#   python -m paper_lib.pipeline.config use <profile>
# `hyperparameters` are the paper's (appendix B), keyed by Gymnasium id.
"""


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML whose mappings may not repeat a key: plain YAML keeps the last one silently, hiding an edit."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        check_unique_keys(self, node)
        return super().construct_mapping(node, deep=deep)


class DuplicateKeyError(yaml.YAMLError):
    """A key given twice in one mapping; `line` and `first` are 1-based."""

    def __init__(self, key: Any, line: int, first: int) -> None:
        super().__init__(f"key {key!r} appears twice in one mapping (lines {first} and {line})")
        self.key, self.line, self.first = key, line, first


def check_unique_keys(loader: yaml.SafeLoader, node: yaml.MappingNode) -> None:
    """The explicit keys of `node` (merge keys `<<` aside: their entries may be overridden) are all different."""
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node, deep=True)
        try:
            if key in seen:  # also twice on one line, as in a flow mapping {a: 1, a: 2}
                raise DuplicateKeyError(key, key_node.start_mark.line + 1, seen[key])
            seen[key] = key_node.start_mark.line + 1
        except TypeError:  # an unhashable key: SafeLoader reports it itself
            continue


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
    seeds: list[int] | dict[str, list[int]]  # one list, or one per env family (MuJoCo, Atari): `seeds_for`
    total_timesteps: int | dict[str, int] | None  # None: each env's own; a mapping: per env (others their own)
    overrides: dict[str, Any]
    n_id_states: int
    n_ood_states: int
    eval_episodes: int
    max_episode_steps: int
    skip_first: int
    deterministic: bool
    inference: str
    n_bootstrap: int
    protocol: str  # "main" (section 5: ood_configs x steps_per_config, id_episodes x steps_per_config) or "appendix"
    ood_configs: int
    id_episodes: int
    steps_per_config: int
    n_scoring_seeds: int  # torch seeds each MC Dropout / DropConnect run is scored under
    hyperparameters: dict[str, dict[str, Any]] = field(repr=False)
    root: Path = Path(".")
    atari_head_root: Path | None = None  # a local Atari-HEAD copy: its frames become the Atari OOD states

    @property
    def layout(self) -> Layout:
        """Where this profile's artifacts live (paper_lib.pipeline.layout, the one home of the paths)."""
        return Layout(self.results)

    @property
    def results(self) -> Path:
        return results_dir(self.root, self.profile)

    def checkpoint_dir(self, env_id: str, method: str, seed: int) -> Path:
        return self.layout.checkpoint_dir(env_id, method, seed)

    def dataset_path(self, env_id: str, method: str, seed: int) -> Path:
        return self.layout.dataset_path(env_id, method, seed)

    @property
    def tables(self) -> Path:
        return self.layout.tables

    @property
    def figures(self) -> Path:
        return self.layout.figures

    def runs(self) -> list[tuple[str, str, int]]:
        return [(e, m, s) for e in self.envs for m in self.methods for s in self.seeds_for(e)]

    def seeds_for(self, env_id: str) -> list[int]:
        """The training seeds of `env_id`'s runs: the profile's list, or its env family's (issue 67: the paper
        profile trains Atari at the paper's 3 seeds and MuJoCo at 5, as registered in `preregistration`)."""
        if isinstance(self.seeds, dict):
            return list(self.seeds[env_family(env_id)])
        return list(self.seeds)

    @property
    def all_seeds(self) -> list[int]:
        """Every seed some env of the profile trains."""
        return seeds_of(self.seeds)

    def seeds_caption(self) -> str:
        if isinstance(self.seeds, dict):
            return "seeds " + ", ".join(f"{family} {seeds}" for family, seeds in self.seeds.items())
        return f"{len(self.seeds)} seed(s) {self.seeds}"

    def budget(self, env_id: str) -> int | None:
        """Training steps of a run in env_id under this profile; None: the env's own (the paper's) budget."""
        if isinstance(self.total_timesteps, dict):
            return self.total_timesteps.get(env_id)
        return self.total_timesteps

    def steps_caption(self) -> str:
        """The training budget in words, for captions."""
        if isinstance(self.total_timesteps, dict):
            changed = ", ".join(f"{env_id} {steps:,}" for env_id, steps in self.total_timesteps.items())
            return f"the paper's (except {changed})"
        return f"{self.total_timesteps:,}" if self.total_timesteps else "the paper's"

    def budget_caption(self) -> str:
        steps = self.steps_caption()
        return (f"profile '{self.profile}': {self.seeds_caption()}, {steps} training steps per run, "
                f"{self.eval_episodes} evaluation episodes; {self.protocol_caption()}; the paper used 3 seeds")

    def protocol_caption(self) -> str:
        """Which collection protocol the ID and OOD states come from, for table captions."""
        skip = f"first {self.skip_first} states of each episode dropped"
        if self.protocol == "main":
            return (f"main-text protocol: OOD states from {self.ood_configs} configurations x {self.steps_per_config} "
                    f"steps, ID states from {self.id_episodes} episodes x {self.steps_per_config} steps, {skip}")
        return (f"appendix G protocol: {self.n_ood_states} OOD states, a new configuration per episode, and "
                f"{self.n_id_states} ID states, at most {self.max_episode_steps} steps per episode, {skip}")


#: The env families a profile's `seeds` may name apart.
SEED_FAMILIES = ("MuJoCo", "Atari")


def env_family(env_id: str) -> str:
    """Atari for the ALE games, MuJoCo for every other env (the classic-control test env included)."""
    from paper_lib.agents.envs import is_atari

    return "Atari" if is_atari(env_id) else "MuJoCo"


def seeds_of(value: list[int] | dict[str, list[int]]) -> list[int]:
    """Every seed a profile's `seeds` names: the list itself, or the union of a per-family mapping."""
    if isinstance(value, dict):
        return sorted({seed for seeds in value.values() for seed in seeds})
    return list(value)


REQUIRED = ("envs", "methods", "seeds", "total_timesteps", "overrides", "n_id_states", "n_ood_states",
            "eval_episodes", "max_episode_steps", "skip_first", "deterministic", "inference", "n_bootstrap",
            "protocol", "ood_configs", "id_episodes", "steps_per_config", "n_scoring_seeds")
#: State collection protocols: the main text's (section 5) and appendix G's.
PROTOCOLS = ("main", "appendix")
#: Settings a profile may leave out (RunConfig gives their defaults).
OPTIONAL: tuple[str, ...] = ()


SECTIONS = ("run", "profiles", "hyperparameters")
#: Sections other parts read with their own loaders (`study`: paper_lib.study.config); kept as they are.
OPTIONAL_SECTIONS = ("study", "guard", "ensembles", "atari_head", "retraining", "preregistration", "pedm")
POSITIVE = ("n_id_states", "n_ood_states", "eval_episodes", "max_episode_steps", "n_bootstrap", "ood_configs",
            "id_episodes", "steps_per_config", "n_scoring_seeds")


def read_params(path: str | Path = PARAMS_FILE) -> dict[str, Any]:
    """params.yaml as a dict; a syntax error is one ValueError naming the file and the line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found; run from the repository root (it holds params.yaml)")
    return parse_params(path.read_text(), path)


def parse_params(text: str, path: str | Path = PARAMS_FILE) -> dict[str, Any]:
    """params.yaml's text as a dict: a syntax error or a key given twice is one ValueError naming file and line."""
    try:
        params = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader subclass)
    except DuplicateKeyError as err:
        raise ValueError(f"{path} line {err.line}: duplicate key {err.key!r}, got it on lines {err.first} and "
                         f"{err.line} of one mapping (YAML would keep only the last, silently); delete one of "
                         "them") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"{path}{where}: YAML syntax error ({problem}); fix that line "
                         "(or restore the file with `git checkout params.yaml`)") from None
    if not isinstance(params, dict) or not set(SECTIONS) <= set(params):
        raise ValueError(f"{path} must have the sections 'profiles', 'run' and 'hyperparameters'; "
                         "restore it with `git checkout params.yaml`")
    unknown = sorted(set(params) - set(SECTIONS) - set(OPTIONAL_SECTIONS))
    if unknown:
        raise ValueError(f"{path}: unknown top-level section(s) {unknown}; params.yaml has only "
                         f"{list(SECTIONS + OPTIONAL_SECTIONS)}")
    return params


def _check_list(value: Any, name: str, where: str) -> list[Any]:
    if not isinstance(value, list) or not value:
        raise ValueError(f"{where}: {name} must be a non-empty list, e.g. [a, b], got {value!r}")
    if len(set(map(repr, value))) != len(value):
        raise ValueError(f"{where}: {name} lists an entry twice: {value!r}")
    return value


def validate_profile(profile: Any, where: str, hps: dict[str, Any]) -> None:
    """Keys, types and ranges of one budget profile (or of `run`)."""
    if not isinstance(profile, dict):
        raise ValueError(f"{where} must be a mapping of settings, got {profile!r}")
    check_keys(profile, where, sorted(set(REQUIRED) | set(OPTIONAL) | {"profile"}), REQUIRED, what="setting")
    for env_id in _check_list(profile["envs"], "envs", where):
        if env_id not in hps:
            raise ValueError(f"{where}: unknown env {env_id!r}; params.yaml has hyperparameters for {sorted(hps)}")
    for method in _check_list(profile["methods"], "methods", where):
        if method not in METHODS:
            raise ValueError(f"{where}: unknown method {method!r}; use one of {METHODS}")
    seeds = profile["seeds"]
    if isinstance(seeds, dict):
        families = sorted({env_family(env_id) for env_id in profile["envs"]})
        check_keys(seeds, f"{where}: seeds", SEED_FAMILIES, families, what="env family",
                   fix="give each env family of the profile's envs its seed list, e.g. {MuJoCo: [0, 1], Atari: [0]}")
        for family, values in seeds.items():
            for seed in _check_list(values, f"seeds.{family}", where):
                check_seed(seed, where)
    else:
        for seed in _check_list(seeds, "seeds", where):
            check_seed(seed, where)
    budget = profile["total_timesteps"]
    if isinstance(budget, dict):
        for env_id, steps in budget.items():
            if env_id not in hps:
                raise ValueError(f"{where}: total_timesteps names unknown env {env_id!r}; params.yaml has "
                                 f"hyperparameters for {sorted(hps)}")
            check_integer(steps, f"total_timesteps.{env_id}", where, minimum=1)
    elif budget is not None:
        check_integer(budget, "total_timesteps", where, minimum=1)
    overrides = profile["overrides"] if profile["overrides"] is not None else {}
    check_algo_settings(overrides, where, name="overrides", required=False)
    for key in POSITIVE:
        if isinstance(profile[key], bool) or not isinstance(profile[key], int) or profile[key] <= 0:
            raise ValueError(f"{where}: {key} must be a positive integer, got {profile[key]!r}")
    check_integer(profile["skip_first"], "skip_first", where, minimum=0)
    if profile["skip_first"] >= profile["max_episode_steps"]:
        raise ValueError(f"{where}: skip_first={profile['skip_first']} drops every state of an episode of "
                         f"max_episode_steps={profile['max_episode_steps']}; make it smaller")
    if not isinstance(profile["deterministic"], bool):
        raise ValueError(f"{where}: deterministic must be true or false, got {profile['deterministic']!r}")
    if profile["inference"] not in INFERENCE_MODES:
        raise ValueError(f"{where}: unknown inference mode {profile['inference']!r}; use one of {INFERENCE_MODES}")
    if profile["protocol"] not in PROTOCOLS:
        raise ValueError(f"{where}: unknown protocol {profile['protocol']!r}; use main (section 5: ood_configs x "
                         "steps_per_config) or appendix (appendix G: n_ood_states, a new configuration per episode)")
    if profile["protocol"] == "main" and profile["id_episodes"] < 2:
        raise ValueError(f"{where}: id_episodes={profile['id_episodes']}: the detectors are fitted on half of the ID "
                         "episodes and evaluated on the other half, so at least 2 are needed")


def validate_params(params: dict[str, Any], path: str | Path = PARAMS_FILE) -> RunConfig:
    """Every section of params.yaml checked (all profiles, all hyperparameters); the active profile returned."""
    path = Path(path)
    run, profiles, hps = params["run"], params["profiles"], params["hyperparameters"]
    for name, section in (("hyperparameters", hps), ("profiles", profiles), ("run", run)):
        if not isinstance(section, dict) or not section:
            raise ValueError(f"{path}: `{name}` must be a non-empty mapping; restore it with `git checkout params.yaml`")
    for env_id, hp in hps.items():
        validate_hyperparameters(hp, env_id, where=f"{path}: hyperparameters.{env_id}")
    check_retraining(params.get("retraining"), hps, path)
    for name, profile in profiles.items():
        validate_profile(profile, f"{path}: profiles.{name}", hps)
        if isinstance(profile, dict) and "profile" in profile:
            raise ValueError(f"{path}: profiles.{name} must not set `profile` (only `run` names its profile)")
    profile = run.get("profile")
    if profile not in profiles:
        raise ValueError(f"{path}: unknown profile {profile!r} in `run`; known: {sorted(profiles)}. "
                         "Fix with `python -m paper_lib.pipeline.config use <profile>`")
    missing = [k for k in REQUIRED if k not in run]
    if missing:
        raise ValueError(f"{path}: `run` lacks {missing}; regenerate it with `python -m paper_lib.pipeline.config use {profile}`")
    validate_profile(run, f"{path}: run", hps)
    for env_id in run["envs"]:  # the settings each training stage will get, checked before any stage runs
        algo = {**hps[env_id]["algo"], **(run["overrides"] or {})}
        check_algo_settings(algo, f"{path}: run with {env_id}")
        k = (hps[env_id].get("members") or {}).get("n_members")
        if k is not None and set(run["methods"]) - {"baseline"}:
            try:
                check_member_layout(hps[env_id]["n_envs"], k, algo["batch_size"], algo["n_steps"])
            except ValueError as err:
                raise ValueError(f"{path}: run with {env_id}: {err}; change `overrides` or the env's hyperparameters") \
                    from None
    return RunConfig(profile=profile, **{k: run[k] for k in REQUIRED}, hyperparameters=hps, root=path.parent,
                     atari_head_root=atari_head_root(params.get("atari_head"), path))


def check_retraining(section: Any, hps: dict[str, Any], path: str | Path = PARAMS_FILE) -> None:
    """`retraining`: recipes whose runs are still training, one per env of `hyperparameters`, each different from it.

    The committed checkpoints' recipe stays in `hyperparameters` (the `train` stages depend on it, so a new recipe
    there would plan retraining of every committed run); an entry equal to it has landed and must go.
    """
    if section is None:
        return
    check_keys(section, f"{path}: retraining", hps, what="env", fix="")
    for env_id, hp in section.items():
        validate_hyperparameters(hp, env_id, where=f"{path}: retraining.{env_id}")
        if hp == hps[env_id]:
            raise ValueError(f"{path}: retraining.{env_id} equals hyperparameters.{env_id}: the recipe has landed; "
                             f"delete retraining.{env_id}")


def atari_head_root(section: Any, path: str | Path = PARAMS_FILE) -> Path | None:
    """The `atari_head.root` of params.yaml: None (the default: game-state OOD sources), else the folder of a
    local Atari-HEAD copy, relative to params.yaml's folder unless absolute. Whether it holds the games is
    checked where its frames are read (`paper_lib.ood.atari_head`), so a wrong path stops only Atari collection."""
    path = Path(path)
    if section is None:
        return None
    if not isinstance(section, dict) or set(section) != {"root"}:
        raise ValueError(f"{path}: `atari_head` must be a mapping with the one key `root` (null, or the folder of a "
                         f"local Atari-HEAD copy), got {section!r}")
    root = section["root"]
    if root is None:
        return None
    if not isinstance(root, str) or not root.strip():
        raise ValueError(f"{path}: atari_head.root must be null or a folder path as a string, got {root!r}")
    root = Path(root).expanduser()
    return root if root.is_absolute() else path.parent / root


def load_run_config(path: str | Path = PARAMS_FILE) -> RunConfig:
    """The active profile from params.yaml, after every section was checked."""
    return validate_params(read_params(path), path)


def _with_run_section(text: str, run: dict[str, Any]) -> str:
    """`text` with its top-level `run:` block replaced by `run`; every other line (comments too) kept as it is."""
    lines = text.splitlines(keepends=True)
    starts = [i for i, line in enumerate(lines) if line.startswith("run:")]
    block = yaml.dump({"run": run}, Dumper=_PlainDumper, sort_keys=False, default_flow_style=None, width=110)
    if not starts:
        return HEADER + block + text
    start = starts[0]
    end = next((i for i in range(start + 1, len(lines))
                if lines[i].strip() and not lines[i][0].isspace()), len(lines))
    return "".join(lines[:start]) + block + "".join(lines[end:])


def check_writable(path: Path) -> None:
    """`use` replaces params.yaml by a rename, which even a read-only file does not stop: refuse one up front."""
    mode = path.stat().st_mode
    if not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH) or not os.access(path, os.W_OK):
        raise ValueError(f"{path} is read-only, got mode {stat.filemode(mode)}; make it writable "
                         f"(chmod u+w {path}) and run again ({path} was left unchanged)")
    folder = path.parent
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"the folder of {path} is read-only, got {folder.resolve()}; make it writable "
                         f"(chmod u+w {folder}) and run again ({path} was left unchanged)")


def use_profile(name: str, path: str | Path = PARAMS_FILE) -> None:
    """Make profile `name` the active one (rewrites the `run` section)."""
    path = Path(path)
    params = read_params(path)
    check_writable(path)
    if name not in params["profiles"]:
        raise ValueError(f"{path}: unknown profile {name!r}; known: {sorted(params['profiles'])}")
    if not isinstance(params["profiles"][name], dict):
        raise ValueError(f"{path}: profiles.{name} must be a mapping of settings; {path} was left unchanged")
    run = {"profile": name, **copy.deepcopy(params["profiles"][name])}
    text = _with_run_section(path.read_text(), run)
    try:  # the file as it would be written, checked before anything is written
        validate_params(parse_params(text, path), path)
    except ValueError as err:
        raise ValueError(f"{err} ({path} was left unchanged)") from None
    try:
        write_text_atomic(path, text)
    except OSError as err:
        raise ValueError(f"cannot write {path}, got {type(err).__name__}: {err}; free space or fix the folder's "
                         f"permissions ({path} was left unchanged)") from None


_ABSENT = object()


def run_differences(params: dict[str, Any]) -> list[str]:
    """The keys of `run` that differ from `profiles.<run.profile>` (an edit of `run` that `use` would undo)."""
    run, profiles = params["run"], params["profiles"]
    if not isinstance(run, dict) or not isinstance(profiles, dict):
        return []
    if not isinstance(profiles.get(run.get("profile")), dict):
        return []
    profile = profiles[run["profile"]]
    keys = sorted((set(run) | set(profile)) - {"profile"})
    return [k for k in keys if run.get(k, _ABSENT) != profile.get(k, _ABSENT)]


def describe_differences(params: dict[str, Any], path: str | Path = PARAMS_FILE) -> str:
    """One line per key of `run` that differs from its profile, and how to restore the profile; "" if none."""
    keys = run_differences(params)
    if not keys:
        return ""
    name = params["run"]["profile"]
    run, profile = params["run"], params["profiles"][name]

    def shown(section: dict[str, Any], key: str) -> str:
        return repr(section[key]) if key in section else "(absent)"

    lines = [f"  {key}: run has {shown(run, key)}, profiles.{name} has {shown(profile, key)}" for key in keys]
    return (f"note: {path}: `run` differs from profiles.{name} in {', '.join(keys)}:\n" + "\n".join(lines)
            + f"\n`python -m paper_lib.pipeline.config use {name}` makes run its copy again "
              f"(or edit profiles.{name} to keep the change)")


def main() -> None:
    parser = argparse.ArgumentParser(description="Switch the pipeline's budget profile.")
    sub = parser.add_subparsers(dest="command", required=True)
    use = sub.add_parser("use", help="make a profile active")
    use.add_argument("profile")
    sub.add_parser("show", help="print the active profile")
    args = parser.parse_args()
    try:
        if args.command == "use":
            use_profile(args.profile)
            from paper_lib.pipeline.run_list import write_run_list  # run_list reads this module's RunConfig

            listed, changed = write_run_list(load_run_config())  # dvc.yaml's per-run stages: the new profile's runs
            if changed:
                print(f"{listed} now lists profile {args.profile!r}'s runs with a checkpoint")
        print(load_run_config())
        if args.command == "show":
            note = describe_differences(read_params(PARAMS_FILE), PARAMS_FILE)
            if note:
                print(note)
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")


if __name__ == "__main__":
    main()
