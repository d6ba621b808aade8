"""What one benchmark run measures: environments, methods, sizes, and the --quick preset."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from paper_lib.agents.envs import is_atari
from paper_lib.agents.factory import paper_hyperparameters
from paper_lib.methods.networks import METHODS

DEFAULT_ENVS = ("HalfCheetah-v5", "SeaquestNoFrameskip-v4")
#: Measured env steps per method when --train-steps is not given: five whole PPO iterations
#: at the paper's settings (~7 s each for plain PPO on HalfCheetah, 2 cores), the speed
#: claim's registered minimum of paired repetitions (params.yaml `preregistration.speed`);
#: more iterations buy less noise at a linear cost.
DEFAULT_TRAIN_STEPS = {"mujoco": 20480, "atari": 5120}
#: Paired repetitions the speed claim needs of each timing it reads (params.yaml
#: `preregistration.speed.min_repetitions`): the large-batch timings run past their time
#: budget until they have this many.
MIN_REPEATS = 5
#: --quick shrinks the rollout only. Update cost per env step is n_epochs / batch_size
#: gradient steps whatever n_steps is, so per-step ratios stay comparable to the full run.
QUICK_N_STEPS = {"mujoco": 64, "atari": 32}
QUICK_TRAIN_STEPS = {"mujoco": 1024, "atari": 512}


def env_kind(env_id: str) -> str:
    return "atari" if is_atari(env_id) else "mujoco"


@dataclass(frozen=True)
class BenchConfig:
    """One benchmark run. Every env gets its paper settings, then `overrides` on top.

    :param train_steps: measured env steps per method (None: a per-env default), rounded up
        to whole PPO iterations (rollout + update); one more iteration is run first as warm-up
    :param n_states: batch for the "score many states" timings (the issue's 4096)
    :param repeats: timing samples per inference measurement (the median is reported; every
        sample goes to bench_timings.csv)
    :param large_budget_s: stop repeating the n_states timings after this many seconds, once
        each has min(repeats, min_repeats) samples: Atari members need ~3-5 s per 4096-state call
    :param min_repeats: samples every timing gets whatever the budget (the speed claim's minimum)
    :param limits: time each inference measurement's arithmetic limit (`bench.limits`)
    :param limit_repeats: timing samples per limit
    :param paper_widths: use the paper's per-method widths (384 for Masksembles on
        HalfCheetah) instead of one width for every method
    """

    envs: tuple[str, ...] = DEFAULT_ENVS
    methods: tuple[str, ...] = METHODS
    train_steps: int | None = None
    n_states: int = 4096
    repeats: int = 5
    large_budget_s: float = 60.0
    min_repeats: int = MIN_REPEATS
    limits: bool = True
    limit_repeats: int = 3
    threads: int = 1
    seed: int = 0
    n_members: int = 4
    memory: bool = True
    memory_jobs: int = 2
    paper_widths: bool = False
    quick: bool = False
    overrides: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise ValueError(f"unknown method(s) {unknown}; use some of {METHODS}")
        if "baseline" not in self.methods:
            raise ValueError("every ratio is against 'baseline' (plain SB3 PPO); keep it in --methods")
        for env_id in self.envs:
            paper_hyperparameters(env_id)  # raises a clear error for an unknown env
        if self.repeats < 1 or self.n_states < 1:
            raise ValueError("--repeats and the number of states must be >= 1")

    def algo_kwargs(self, env_id: str) -> dict[str, Any]:
        """PPO settings for `env_id`: the paper's, shrunk by --quick, then `overrides`."""
        hp = paper_hyperparameters(env_id)
        quick = {"n_steps": QUICK_N_STEPS[env_kind(env_id)]} if self.quick else {}
        unknown = set(self.overrides) - set(hp["algo"])
        if unknown:
            raise ValueError(f"unknown override(s) {sorted(unknown)}; known settings are {sorted(hp['algo'])}")
        return {**hp["algo"], **quick, **self.overrides}

    def n_envs(self, env_id: str) -> int:
        return int(paper_hyperparameters(env_id)["n_envs"])

    def hidden_sizes(self, env_id: str, method: str) -> list[int]:
        """The MLP widths; the same for every method unless `paper_widths`. Empty for Atari: its
        Nature CNN has the same sizes in every method already."""
        hp = paper_hyperparameters(env_id)
        if self.paper_widths and method == "masksembles" and "hidden_sizes_masksembles" in hp:
            return list(hp["hidden_sizes_masksembles"])
        return list(hp.get("hidden_sizes", []))

    def rollout_steps(self, env_id: str) -> int:
        return int(self.algo_kwargs(env_id)["n_steps"]) * self.n_envs(env_id)

    def iterations(self, env_id: str) -> int:
        """Measured PPO iterations (after warm-up) for `env_id`."""
        kind = env_kind(env_id)
        steps = self.train_steps or (QUICK_TRAIN_STEPS if self.quick else DEFAULT_TRAIN_STEPS)[kind]
        return max(1, math.ceil(steps / self.rollout_steps(env_id)))

    def settings(self, env_id: str, method: str) -> str:
        """One readable line of what was run, stored in every CSV row."""
        a = self.algo_kwargs(env_id)
        net = "NatureCNN-512" if is_atari(env_id) else "x".join(map(str, self.hidden_sizes(env_id, method)))
        members = "" if method == "baseline" else f" k={self.n_members}"
        return (f"n_envs={self.n_envs(env_id)} n_steps={a['n_steps']} batch_size={a['batch_size']} "
                f"n_epochs={a['n_epochs']} net={net}{members}")


def quick_config(**kwargs: Any) -> BenchConfig:
    """The ~1 minute preset: short rollouts, 256 states, 3 repeats, small time budgets, and no
    memory children (20 fresh processes cost ~3 s of imports each: as long as all the rest)."""
    preset: dict[str, Any] = dict(quick=True, n_states=256, repeats=3, large_budget_s=5.0, memory=False)
    return BenchConfig(**{**preset, **kwargs})
