"""params.yaml's `study` section -> a validated study configuration for one budget profile.

The section has five parts, all data, and one optional mapping:
- `objective`: how a trial is scored (reward's action mode, the noise OOD set, the AUROC measure);
- `space`: the search space per algorithm (`ppo`, `a2c`, `trpo`), for the network and per method;
- `ablations`: which sampled setting is each method's ablation axis (number of members, dropout p);
- `budgets`: per profile (tiny, cpu, paper) which studies run, how many trials, how long each trains;
- `scaling`: per profile, the hidden-layer widths of appendix E's scaling runs;
- `budget_of_profile` (optional): which budget a run profile's study and scaling use, when not its own
  (`paper: cpu`: the committed profile's study runs at the CPU budget, into results/paper/, and says so).

Every error is raised here, with the key that is wrong and what to write, before any worker starts.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from paper_lib.agents.factory import ALGO_KEYS, ALGORITHMS
from paper_lib.measures.definitions import MEMBER_MEASURES
from paper_lib.methods.networks import METHODS
from paper_lib.methods.policy import INFERENCE_MODES
from paper_lib.pipeline.config import PARAMS_FILE, check_keys, read_params
from paper_lib.pipeline.layout import Layout
from paper_lib.study.space import ParamSpec, parse_space

SAMPLERS = ("tpe", "nsga2", "random")
#: Scores a trial can optimize: the member measures, and the member-free detectors (baseline studies).
DETECTORS = ("mahalanobis_obs", "knn_obs", "mahalanobis_features", "knn_features")
PARTS = ("objective", "space", "ablations", "budgets", "scaling")
OPTIONAL_PARTS = ("budget_of_profile",)
#: Keys of the space that do not go to the algorithm: the network and the member settings.
NETWORK_KEYS = ("width", "activation_fn", "log_std_init")
MEMBER_KEYS = ("n_members", "dropout_p", "masksembles_scale")


def _mapping(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ValueError(f"{where} must be a mapping (key: value), got {value!r}")
    return value


def _positive_int(value: Any, where: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{where} must be an integer >= {minimum}, got {value!r}")
    return value


@dataclass(frozen=True)
class Objective:
    """How one trained configuration becomes the two numbers the study maximizes."""

    deterministic_reward: bool
    noise_magnitude: float
    measure: str
    baseline_measure: str
    collect_deterministic: bool
    inference: str

    def auroc_measure(self, method: str) -> str:
        return self.baseline_measure if method == "baseline" else self.measure


@dataclass(frozen=True)
class StudySpec:
    """One Optuna study: an algorithm, an env and a method, with its search space and budget."""

    algo: str
    env_id: str
    method: str
    n_trials: int
    total_timesteps: int | None
    fixed: dict[str, Any]
    space: dict[str, ParamSpec]

    @property
    def name(self) -> str:
        return study_name(self.algo, self.env_id, self.method)

    def identity(self) -> dict[str, Any]:
        """What a study stored in a database must agree with (the trial count may grow)."""
        return {"algo": self.algo, "env_id": self.env_id, "method": self.method,
                "total_timesteps": self.total_timesteps, "fixed": self.fixed,
                "space": {k: v.to_dict() for k, v in self.space.items()}}


@dataclass(frozen=True)
class Heartbeat:
    interval: int
    grace_period: int
    max_retry: int


@dataclass(frozen=True)
class StudyConfig:
    """One profile's studies, with everything a worker needs to run a trial of any of them."""

    profile: str  # the run profile: results go to results/<profile>/
    budget: str  # the budget (study.budgets.<budget>) its studies use
    seed: int
    studies: dict[str, StudySpec]
    eval_episodes: int
    n_id_states: int
    max_episode_steps: int
    skip_first: int
    sampler: dict[str, Any]
    heartbeat: Heartbeat
    objective: Objective
    ablations: dict[str, list[str]]
    hyperparameters: dict[str, dict[str, Any]] = field(repr=False)
    root: Path = Path(".")

    @property
    def layout(self) -> Layout:
        """Where the profile's artifacts live (paper_lib.pipeline.layout)."""
        return Layout.of(self.root, self.profile)

    @property
    def results(self) -> Path:
        return self.layout.results

    @property
    def studies_dir(self) -> Path:
        return self.layout.studies

    def default_storage_url(self) -> str:
        """The embedded local store: one SQLite file per profile (resumes after a kill, opens in optuna-dashboard)."""
        return f"sqlite:///{self.layout.studies_db.resolve()}"

    def study(self, name: str) -> StudySpec:
        if name not in self.studies:
            raise ValueError(f"unknown study {name!r} in profile {self.profile!r}; its studies are "
                             f"{sorted(self.studies)} (names are <algo>-<env>-<method>)")
        return self.studies[name]

    def short_caption(self, algo: str | None = None) -> str:
        """The budget in a figure title: trials per study and training steps per trial, against the paper's."""
        specs = [s for s in self.studies.values() if algo is None or s.algo == algo]
        trials = "/".join(map(str, sorted({s.n_trials for s in specs})))
        steps = "/".join(sorted({str(s.total_timesteps or "full") for s in specs}))
        return f"{budget_label(self.profile, self.budget)}: {trials} trials/study, {steps} steps/trial (paper: 190 trials, full budget)"

    def budget_caption(self, algo: str | None = None) -> str:
        """What every study caption says: trials, training steps and evaluation, against the paper's."""
        specs = [s for s in self.studies.values() if algo is None or s.algo == algo]
        trials = sorted({s.n_trials for s in specs})
        steps = sorted({str(s.total_timesteps or "the paper's") for s in specs})
        o = self.objective
        return (f"{budget_label(self.profile, self.budget)}: {'/'.join(map(str, trials))} trials per study, {'/'.join(steps)} training "
                f"steps per trial, {self.eval_episodes} evaluation episodes "
                f"({'deterministic' if o.deterministic_reward else 'sampled'} actions), AUROC on noise OOD "
                f"({o.noise_magnitude:g}x ID std) of {self.n_id_states} ID states from {o.measure} "
                f"(baseline: {o.baseline_measure}); the paper: 190 trials per study at the full training budget")


def budget_label(profile: str, budget: str) -> str:
    """How captions name the budget: the profile, and the budget where the profile borrows another's."""
    return f"profile '{profile}'" if budget == profile else f"profile '{profile}' at the '{budget}' study budget"


def resolve_budget(params: dict[str, Any], profile: str, path: Path, part: str, known: list[str]) -> str:
    """The entry of `study.<part>` run profile `profile` uses: `study.budget_of_profile[profile]`, else its own."""
    mapping = _mapping((params.get("study") or {}).get("budget_of_profile") or {}, f"{path}: study.budget_of_profile")
    if profile not in mapping:
        if profile not in known:
            raise ValueError(f"{path}: study.{part} has no profile {profile!r}; known: {known}")
        return profile
    if mapping[profile] not in known:
        raise ValueError(f"{path}: study.budget_of_profile maps profile {profile!r} to {mapping[profile]!r}, which "
                         f"study.{part} lacks; use one of {known}")
    return mapping[profile]


def study_name(algo: str, env_id: str, method: str) -> str:
    return f"{algo}-{env_id}-{method}"


def parse_study_name(name: str) -> tuple[str, str, str]:
    """<algo>-<env>-<method> -> (algo, env, method); env ids contain dashes, algorithms and methods do not."""
    algo, _, rest = name.partition("-")
    env_id, _, method = rest.rpartition("-")
    if algo not in ALGORITHMS or method not in METHODS or not env_id:
        raise ValueError(f"study name {name!r} is not <algo>-<env>-<method> with algo in {sorted(ALGORITHMS)} and "
                         f"method in {METHODS}, e.g. ppo-HalfCheetah-v5-masksembles")
    return algo, env_id, method


def _objective(raw: Any, where: str) -> Objective:
    keys = ("deterministic_reward", "noise_magnitude", "measure", "baseline_measure", "collect_deterministic",
            "inference")
    raw = check_keys(raw, where, keys, keys)
    for key in ("deterministic_reward", "collect_deterministic"):
        if not isinstance(raw[key], bool):
            raise ValueError(f"{where}.{key} must be true or false, got {raw[key]!r}")
    magnitude = raw["noise_magnitude"]
    if isinstance(magnitude, bool) or not isinstance(magnitude, (int, float)) or not magnitude > 0:
        raise ValueError(f"{where}.noise_magnitude must be a positive number (the paper: 2.0), got {magnitude!r}")
    if raw["measure"] not in MEMBER_MEASURES + DETECTORS:
        raise ValueError(f"{where}.measure={raw['measure']!r}; use one of {MEMBER_MEASURES + DETECTORS}")
    if raw["baseline_measure"] not in DETECTORS:
        raise ValueError(f"{where}.baseline_measure={raw['baseline_measure']!r}: a baseline has no members; "
                         f"use a member-free detector, one of {DETECTORS}")
    if raw["inference"] not in INFERENCE_MODES:
        raise ValueError(f"{where}.inference={raw['inference']!r}; use one of {INFERENCE_MODES}")
    return Objective(raw["deterministic_reward"], float(magnitude), raw["measure"], raw["baseline_measure"],
                     raw["collect_deterministic"], raw["inference"])


def _algo_keys(algo: str, hps: dict[str, Any], env_id: str) -> tuple[str, ...]:
    """The algorithm settings make_agent passes on for `algo` (the others it drops, so they must not be searched)."""
    table = tuple(hps[env_id]["algo"])
    return table if ALGO_KEYS[algo] is None else tuple(k for k in ALGO_KEYS[algo] if k in table)


def _study_specs(algo: str, entry: Any, space: dict[str, Any], hps: dict[str, Any], where: str) -> list[StudySpec]:
    keys = ("envs", "methods", "n_trials", "total_timesteps", "fixed", "space")
    entry = check_keys(entry, where, keys, ("envs", "methods", "n_trials", "total_timesteps"))
    for key in ("envs", "methods"):
        if not isinstance(entry[key], list) or not entry[key] or len(set(entry[key])) != len(entry[key]):
            raise ValueError(f"{where}.{key} must be a non-empty list without repeats, got {entry[key]!r}")
    n_trials = _positive_int(entry["n_trials"], f"{where}.n_trials")
    steps = entry["total_timesteps"]
    if steps is not None:
        _positive_int(steps, f"{where}.total_timesteps (a number of steps, or null for each env's full budget)")
    fixed = dict(_mapping(entry.get("fixed") or {}, f"{where}.fixed"))
    replaced = parse_space(_mapping(entry.get("space") or {}, f"{where}.space"), f"{where}.space")
    specs = []
    for env_id in entry["envs"]:
        if env_id not in hps:
            raise ValueError(f"{where}: unknown env {env_id!r}; params.yaml has hyperparameters for {sorted(hps)}")
        takes = _algo_keys(algo, hps, env_id)
        algo_space = {**space["algos"].get(algo, {}), **{k: v for k, v in replaced.items() if k not in NETWORK_KEYS
                                                           + MEMBER_KEYS}}
        for key in list(algo_space) + [k for k in fixed if k not in NETWORK_KEYS + MEMBER_KEYS]:
            if key not in takes:
                raise ValueError(f"{where}: {algo.upper()} does not take {key!r} (make_agent passes it only "
                                 f"{list(takes)}); remove it from study.space.{algo}, `fixed` or `space`")
        for method in entry["methods"]:
            if method not in METHODS:
                raise ValueError(f"{where}: unknown method {method!r}; use one of {METHODS}")
            merged = {**algo_space, **space["network"], **space["members"].get(method, {})}
            merged.update({k: v for k, v in replaced.items() if k in NETWORK_KEYS or k in MEMBER_KEYS})
            for key in fixed:
                merged.pop(key, None)
            specs.append(StudySpec(algo, env_id, method, n_trials, steps, fixed, merged))
    return specs


def _space(raw: Any, where: str) -> dict[str, Any]:
    raw = check_keys(raw, where, (*ALGORITHMS, "network", "members"), ("network", "members"))
    algos = {a: parse_space(_mapping(raw[a], f"{where}.{a}"), f"{where}.{a}") for a in ALGORITHMS if a in raw}
    network = parse_space(_mapping(raw["network"], f"{where}.network"), f"{where}.network")
    check_keys(network, f"{where}.network", NETWORK_KEYS)
    members_raw = check_keys(raw["members"], f"{where}.members", METHODS)
    members = {}
    for method, entry in members_raw.items():
        members[method] = parse_space(_mapping(entry or {}, f"{where}.members.{method}"), f"{where}.members.{method}")
        check_keys(members[method], f"{where}.members.{method}", () if method == "baseline" else MEMBER_KEYS)
    return {"algos": algos, "network": network, "members": members}


def _ablations(raw: Any, where: str) -> dict[str, list[str]]:
    raw = check_keys(raw, where, MEMBER_KEYS)
    for axis, methods in raw.items():
        if not isinstance(methods, list) or not set(methods) <= set(METHODS) - {"baseline"}:
            raise ValueError(f"{where}.{axis} must list member methods from {METHODS[1:]}, got {methods!r}")
    return {axis: list(methods) for axis, methods in raw.items()}


def load_study_config(path: str | Path = PARAMS_FILE, profile: str | None = None) -> StudyConfig:
    """The study configuration of `profile` (default: the active profile, params.yaml's `run.profile`)."""
    path = Path(path)
    params = read_params(path)
    if "study" not in params:
        raise ValueError(f"{path} has no `study` section; restore it with `git checkout params.yaml`")
    section = check_keys(params["study"], f"{path}: study", PARTS + OPTIONAL_PARTS, PARTS)
    profile = profile or (params.get("run") or {}).get("profile")
    budgets = _mapping(section["budgets"], f"{path}: study.budgets")
    budget_key = resolve_budget(params, profile, path, "budgets", sorted(budgets))
    hps = params["hyperparameters"]
    where = f"{path}: study.budgets.{budget_key}"
    keys = ("seed", "studies", "eval_episodes", "n_id_states", "max_episode_steps", "skip_first", "sampler",
            "heartbeat")
    budget = check_keys(budgets[budget_key], where, keys, keys)
    space = _space(section["space"], f"{path}: study.space")
    studies_raw = check_keys(budget["studies"], f"{where}.studies", ALGORITHMS)
    studies: dict[str, StudySpec] = {}
    for algo, entry in studies_raw.items():
        if algo not in space["algos"]:
            raise ValueError(f"{where}.studies.{algo}: study.space has no `{algo}` search space; add one")
        for spec in _study_specs(algo, entry, space, hps, f"{where}.studies.{algo}"):
            studies[spec.name] = spec
    for key in ("eval_episodes", "n_id_states", "max_episode_steps"):
        _positive_int(budget[key], f"{where}.{key}")
    _positive_int(budget["n_id_states"], f"{where}.n_id_states", minimum=4)
    _positive_int(budget["skip_first"], f"{where}.skip_first", minimum=0)
    if budget["skip_first"] >= budget["max_episode_steps"]:
        raise ValueError(f"{where}: skip_first={budget['skip_first']} drops every state of an episode of "
                         f"max_episode_steps={budget['max_episode_steps']}; make it smaller")
    _positive_int(budget["seed"], f"{where}.seed", minimum=0)
    sampler = dict(_mapping(budget["sampler"], f"{where}.sampler"))
    if sampler.get("name") not in SAMPLERS:
        raise ValueError(f"{where}.sampler.name={sampler.get('name')!r}; use one of {SAMPLERS} (multi-objective)")
    beat_keys = ("interval", "grace_period", "max_retry")
    beat = check_keys(budget["heartbeat"], f"{where}.heartbeat", beat_keys, beat_keys)
    heartbeat = Heartbeat(_positive_int(beat["interval"], f"{where}.heartbeat.interval"),
                          _positive_int(beat["grace_period"], f"{where}.heartbeat.grace_period"),
                          _positive_int(beat["max_retry"], f"{where}.heartbeat.max_retry", minimum=0))
    if heartbeat.grace_period <= heartbeat.interval:
        raise ValueError(f"{where}.heartbeat: grace_period={heartbeat.grace_period} must exceed interval="
                         f"{heartbeat.interval} seconds, or live trials are declared dead; e.g. 5x the interval")
    return StudyConfig(profile=profile, budget=budget_key, seed=budget["seed"], studies=studies, eval_episodes=budget["eval_episodes"],
                       n_id_states=budget["n_id_states"], max_episode_steps=budget["max_episode_steps"],
                       skip_first=budget["skip_first"], sampler=sampler, heartbeat=heartbeat,
                       objective=_objective(section["objective"], f"{path}: study.objective"),
                       ablations=_ablations(section["ablations"], f"{path}: study.ablations"),
                       hyperparameters=copy.deepcopy(hps), root=path.parent)

