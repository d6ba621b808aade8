"""Wall-clock measurements: PPO training throughput, the env-stepping ceiling, inference.

The machine is shared and noisy, so every measurement interleaves the methods (round-robin,
rotating who goes first) instead of timing one method after another: slow drifts in
background load then hit all methods alike and the ratios survive them.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from paper_lib.bench.models import random_actions


@dataclass
class TrainTiming:
    """Per-iteration wall times of one method's measured PPO iterations."""

    steps_per_iteration: int
    rollout_s: list[float] = field(default_factory=list)
    update_s: list[float] = field(default_factory=list)

    @property
    def steps_per_s(self) -> float:
        return self.steps_per_iteration * len(self.rollout_s) / (sum(self.rollout_s) + sum(self.update_s))


class _RolloutClock(BaseCallback):
    """Times the rollout (collection) part of a learn() iteration; the rest is the update."""

    def __init__(self) -> None:
        super().__init__()
        self.started = 0.0
        self.seconds = 0.0

    def _on_rollout_start(self) -> None:
        self.started = time.perf_counter()

    def _on_rollout_end(self) -> None:
        self.seconds = time.perf_counter() - self.started

    def _on_step(self) -> bool:
        return True


def _one_iteration(model: PPO, first: bool) -> tuple[float, float]:
    """Run exactly one PPO iteration (rollout + update); return (rollout_s, update_s)."""
    clock = _RolloutClock()
    steps = model.n_steps * model.n_envs
    started = time.perf_counter()
    model.learn(steps, callback=clock, reset_num_timesteps=first)
    total = time.perf_counter() - started
    return clock.seconds, total - clock.seconds


def _rotated(names: list[str], shift: int) -> list[str]:
    shift %= len(names)
    return names[shift:] + names[:shift]


def train_throughput(models: dict[str, PPO], iterations: int) -> dict[str, TrainTiming]:
    """One warm-up iteration per model, then `iterations` measured ones, interleaved across models."""
    names = list(models)
    for name in names:
        _one_iteration(models[name], first=True)
    timings = {name: TrainTiming(models[name].n_steps * models[name].n_envs) for name in names}
    for i in range(iterations):
        for name in _rotated(names, i):
            rollout, update = _one_iteration(models[name], first=False)
            timings[name].rollout_s.append(rollout)
            timings[name].update_s.append(update)
    return timings


def env_ceiling(env: VecEnv, env_steps: int, keep_states: int) -> tuple[float, np.ndarray]:
    """Env steps/s of `env` under random actions (the most PPO could reach), and up to
    `keep_states` of the observations seen (an append per step: negligible next to a step)."""
    obs = env.reset()
    kept = [obs]
    calls = max(1, math.ceil(env_steps / env.num_envs))
    started = time.perf_counter()
    for _ in range(calls):
        obs, _, _, _ = env.step(random_actions(env))
        if len(kept) * env.num_envs < keep_states:
            kept.append(obs)
    seconds = time.perf_counter() - started
    return calls * env.num_envs / seconds, np.concatenate(kept)


#: A call at least this long is its own warm-up: first-call effects vanish next to it, and
#: repeating an Atari ensemble's 20 s call only to warm it up would double the benchmark.
LONG_CALL_S = 1.0


def _calibrate(fn: Callable[[], object], min_sample_s: float) -> tuple[int, list[float]]:
    """Calls per timing sample (one sample lasts >= `min_sample_s`, above timer noise).

    Returns the count and the samples already taken (the first call, if it was long).
    """
    started = time.perf_counter()
    fn()
    first = time.perf_counter() - started
    if first >= LONG_CALL_S:
        return 1, [first]
    started = time.perf_counter()
    fn()
    once = max(time.perf_counter() - started, 1e-7)
    return max(1, math.ceil(min_sample_s / once)), []


def interleaved_samples(fns: dict[str, Callable[[], object]], repeats: int, budget_s: float = math.inf,
                        min_sample_s: float = 0.02, min_samples: int = 1) -> dict[str, list[float]]:
    """Every timing sample (seconds per call) of each function, in the order taken.

    Each round times every function still short of `repeats` samples once, in a rotating
    order; rounds stop once `budget_s` seconds (calibration included) have passed and every
    function has `min_samples` samples (at least one: never none). Sample i of two functions
    is taken in the same round (a long first call counts as its function's first sample), so
    samples pair by position: the speed claim compares methods on such pairs.
    """
    names = list(fns)
    floor = max(1, min(min_samples, repeats))
    started = time.perf_counter()
    inner, samples = {}, {}
    for name in names:
        inner[name], samples[name] = _calibrate(fns[name], min_sample_s)
    r = 0
    while True:
        due = [n for n in _rotated(names, r) if len(samples[n]) < repeats]
        over_budget = time.perf_counter() - started > budget_s and all(len(samples[n]) >= floor for n in names)
        if not due or over_budget:
            break
        for name in due:
            t0 = time.perf_counter()
            for _ in range(inner[name]):
                fns[name]()
            samples[name].append((time.perf_counter() - t0) / inner[name])
        r += 1
    return samples


def interleaved_medians(fns: dict[str, Callable[[], object]], repeats: int, budget_s: float = math.inf,
                        min_sample_s: float = 0.02, min_samples: int = 1) -> dict[str, tuple[float, int]]:
    """Median seconds per call of each function, and the number of samples it is taken from
    (`interleaved_samples`)."""
    samples = interleaved_samples(fns, repeats, budget_s, min_sample_s, min_samples)
    return {name: (statistics.median(s), len(s)) for name, s in samples.items()}
