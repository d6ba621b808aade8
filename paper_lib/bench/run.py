"""One benchmark run: for each env, the ceiling, training, inference and memory, as Rows."""

from __future__ import annotations

import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO

from paper_lib.bench import memory
from paper_lib.bench.arithmetic import measurement_count
from paper_lib.bench.config import BenchConfig
from paper_lib.bench.limits import dense_limit
from paper_lib.bench.models import build_model, has_measures, make_bench_env
from paper_lib.bench.report import (COMPILED_ACT, ENV_ONLY, LIMIT_PREFIX, RATE_UNIT, Row, Sample, with_limits,
                                    with_ratios, write_outputs)
from paper_lib.bench.timing import env_ceiling, interleaved_samples, train_throughput
from paper_lib.deploy import NotCompilable, compile_policy
from paper_lib.measures.estimates import act_with_uncertainty, uncertainty
from paper_lib.methods.policy import MemberActorCriticPolicy


def _log(message: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


def machine_line() -> str:
    return (f"{platform.platform()}; {platform.processor() or platform.machine()}; {os.cpu_count()} CPUs; "
            f"torch {th.__version__}")


def _tile(states: np.ndarray, n: int) -> np.ndarray:
    """Exactly n states: repeat the collected ones when the ceiling run saw fewer."""
    return np.resize(states, (n, *states.shape[1:])) if len(states) != n else states


def _inference_fns(models: dict[str, PPO], states: np.ndarray) -> tuple[dict, dict]:
    """(batch-1 calls, n-states calls), keyed by (method, measurement). Uncertainty runs on the "fast" lean path
    (`inference.PATHS`: the exact one's numbers up to float rounding), as `act_with_uncertainty` and `predict` do."""
    one, n = states[:1], len(states)
    small: dict[tuple[str, str], Callable[[], object]] = {}
    large: dict[tuple[str, str], Callable[[], object]] = {}
    for method, model in models.items():
        small[method, "predict_b1"] = lambda m=model: m.predict(one, deterministic=True)
        large[method, f"predict_b{n}"] = lambda m=model: m.predict(states, deterministic=True)
        if has_measures(model, method):
            if isinstance(model.policy, MemberActorCriticPolicy):  # one pass for the action and the measures
                small[method, "act_uncertainty_b1"] = lambda m=model: act_with_uncertainty(m.policy, one)
                try:  # the same call on the compiled policy (Masksembles and Ensemble MLPs)
                    compiled = compile_policy(model.policy)
                    small[method, COMPILED_ACT] = lambda c=compiled: c.act_with_uncertainty(one)
                except NotCompilable:
                    pass
            else:  # a discrete baseline's max_prob / entropy: predict, then score
                small[method, "act_uncertainty_b1"] = lambda m=model: (m.predict(one, deterministic=True),
                                                                       uncertainty(m.policy, one, path="fast"))
            large[method, f"uncertainty_b{n}"] = lambda m=model: uncertainty(m.policy, states, path="fast")
    return small, large


def _limit_fns(models: dict[str, PPO], fns: dict, n_states: int, discrete: bool
               ) -> tuple[dict, dict[tuple[str, str], tuple[float, float]]]:
    """Per timed (method, measurement): its limit's function, and (multiply-adds per state, scale)."""
    limit_fns, counts = {}, {}
    for method, name in fns:
        count = measurement_count(models[method].policy, name, discrete)
        if count is None:
            continue
        limit = dense_limit(count, 1 if name.endswith("_b1") else n_states)
        limit_fns[method, name] = limit.run
        counts[method, name] = (float(count.macs), limit.scale)
    return limit_fns, counts


def bench_env(config: BenchConfig, env_id: str) -> tuple[list[Row], list[Sample]]:
    """Every measurement of one env, as Rows without ratios, and every timing repetition."""
    rows: list[Row] = []
    samples: list[Sample] = []

    def add(method: str, measurement: str, value: float, unit: str, n: int) -> None:
        if method == ENV_ONLY:
            settings = "random actions, " + config.settings(env_id, "baseline")
        else:
            settings = config.settings(env_id, method)
        rows.append(Row(env_id, method, measurement, value, unit, n, settings))

    def keep(method: str, measurement: str, values: list[float], unit: str) -> None:
        samples.extend(Sample(env_id, method, measurement, i, v, unit) for i, v in enumerate(values))

    iterations, rollout = config.iterations(env_id), config.rollout_steps(env_id)
    _log(f"{env_id}: env-stepping ceiling, {iterations * rollout} steps")
    env = make_bench_env(config, env_id)
    rate, states = env_ceiling(env, iterations * rollout, config.n_states)
    env.close()
    add(ENV_ONLY, "env_steps_per_s", rate, RATE_UNIT, 1)

    models = {method: build_model(config, env_id, method) for method in config.methods}
    _log(f"{env_id}: training, {len(models)} methods x (1 warm-up + {iterations}) iterations of {rollout} steps")
    for method, timing in train_throughput(models, iterations).items():
        add(method, "train_steps_per_s", timing.steps_per_s, RATE_UNIT, len(timing.rollout_s))
        add(method, "rollout_s_per_iter", float(np.median(timing.rollout_s)), "s", len(timing.rollout_s))
        add(method, "update_s_per_iter", float(np.median(timing.update_s)), "s", len(timing.update_s))
        keep(method, "train_steps_per_s", [timing.steps_per_iteration / (r + u)
                                           for r, u in zip(timing.rollout_s, timing.update_s)], RATE_UNIT)
        keep(method, "rollout_s_per_iter", timing.rollout_s, "s")
        keep(method, "update_s_per_iter", timing.update_s, "s")

    small, large = _inference_fns(models, _tile(states, config.n_states))
    _log(f"{env_id}: inference, batch 1 and {config.n_states} states, up to {config.repeats} repeats")
    for fns, budget in ((small, float("inf")), (large, config.large_budget_s)):
        timed = interleaved_samples(fns, config.repeats, budget, min_samples=config.min_repeats)
        for (method, name), seconds in timed.items():
            add(method, name, float(np.median(seconds)) * 1e3, "ms", len(seconds))
            keep(method, name, [s * 1e3 for s in seconds], "ms")

    limits: dict[tuple[str, str, str], tuple[float, float]] = {}
    if config.limits:
        discrete = isinstance(next(iter(models.values())).action_space, spaces.Discrete)
        _log(f"{env_id}: the arithmetic limits, up to {config.limit_repeats} repeats")
        for fns, budget in ((small, float("inf")), (large, config.large_budget_s)):
            limit_fns, counts = _limit_fns(models, fns, config.n_states, discrete)
            for (method, name), seconds in interleaved_samples(limit_fns, config.limit_repeats, budget).items():
                macs, scale = counts[method, name]
                values = [s * scale * 1e3 for s in seconds]
                limits[env_id, method, name] = (macs, float(np.median(values)))
                keep(method, LIMIT_PREFIX + name, values, "ms")
    for model in models.values():
        model.env.close()

    if config.memory:
        _log(f"{env_id}: peak memory, {2 * len(config.methods)} fresh processes, {config.memory_jobs} at a time")
        for (method, phase), mb in memory.measure_all(config, env_id).items():
            add(method, f"peak_rss_{phase}_mb", mb["peak_mb"], "MB", 1)
            add(method, f"rss_increase_{phase}_mb", mb["peak_mb"] - mb["floor_mb"], "MB", 1)
    return with_limits(_ordered(rows, config), limits), samples


def _ordered(rows: list[Row], config: BenchConfig) -> list[Row]:
    """Method order as given, measurements in the order measured."""
    order = {m: i for i, m in enumerate((ENV_ONLY, *config.methods))}
    return sorted(rows, key=lambda r: order[r.method])


def run_benchmark(config: BenchConfig, out_dir: str | Path = "results/bench") -> tuple[list[Row], str]:
    """Measure every env in `config`, write bench.csv, bench.md and bench_timings.csv (every repetition) to
    `out_dir`; return rows and Markdown."""
    th.set_num_threads(config.threads)
    load_start = os.getloadavg()[0]
    started = time.perf_counter()
    rows: list[Row] = []
    samples: list[Sample] = []
    for env_id in config.envs:
        env_rows, env_samples = bench_env(config, env_id)
        rows += env_rows
        samples += env_samples
    context = dict(torch_threads=th.get_num_threads(), machine=machine_line(), load_avg_1m=round(load_start, 2))
    rows = with_ratios([replace(r, **context) for r in rows])
    header = (f"Machine: {context['machine']}. Torch threads: {context['torch_threads']}. "
              f"Load average (1 min) before the run {load_start:.2f} (above ~0: other processes shared the CPUs, "
              f"absolute numbers are disturbed, ratios less so). Took {time.perf_counter() - started:.0f} s.")
    _, _, markdown = write_outputs(rows, out_dir, header, samples)
    return rows, markdown
