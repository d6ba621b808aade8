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
from stable_baselines3 import PPO

from paper_lib.bench import memory
from paper_lib.bench.config import BenchConfig
from paper_lib.bench.models import build_model, has_measures, make_bench_env
from paper_lib.bench.report import ENV_ONLY, RATE_UNIT, Row, with_ratios, write_outputs
from paper_lib.bench.timing import env_ceiling, interleaved_medians, train_throughput
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
    """(batch-1 calls, n-states calls), keyed by (method, measurement)."""
    one, n = states[:1], len(states)
    small: dict[tuple[str, str], Callable[[], object]] = {}
    large: dict[tuple[str, str], Callable[[], object]] = {}
    for method, model in models.items():
        small[method, "predict_b1"] = lambda m=model: m.predict(one, deterministic=True)
        large[method, f"predict_b{n}"] = lambda m=model: m.predict(states, deterministic=True)
        if has_measures(model, method):
            if isinstance(model.policy, MemberActorCriticPolicy):  # one pass for the action and the measures
                small[method, "act_uncertainty_b1"] = lambda m=model: act_with_uncertainty(m.policy, one)
            else:  # a discrete baseline's max_prob / entropy: predict, then score
                small[method, "act_uncertainty_b1"] = lambda m=model: (m.predict(one, deterministic=True),
                                                                       uncertainty(m.policy, one))
            large[method, f"uncertainty_b{n}"] = lambda m=model: uncertainty(m.policy, states)
    return small, large


def bench_env(config: BenchConfig, env_id: str) -> list[Row]:
    """Every measurement of one env, as Rows without ratios."""
    rows: list[Row] = []

    def add(method: str, measurement: str, value: float, unit: str, samples: int) -> None:
        if method == ENV_ONLY:
            settings = "random actions, " + config.settings(env_id, "baseline")
        else:
            settings = config.settings(env_id, method)
        rows.append(Row(env_id, method, measurement, value, unit, samples, settings))

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

    small, large = _inference_fns(models, _tile(states, config.n_states))
    _log(f"{env_id}: inference, batch 1 and {config.n_states} states, up to {config.repeats} repeats")
    for fns, budget in ((small, float("inf")), (large, config.large_budget_s)):
        for (method, name), (seconds, samples) in interleaved_medians(fns, config.repeats, budget).items():
            add(method, name, seconds * 1e3, "ms", samples)
    for model in models.values():
        model.env.close()

    if config.memory:
        _log(f"{env_id}: peak memory, {2 * len(config.methods)} fresh processes, {config.memory_jobs} at a time")
        for (method, phase), mb in memory.measure_all(config, env_id).items():
            add(method, f"peak_rss_{phase}_mb", mb["peak_mb"], "MB", 1)
            add(method, f"rss_increase_{phase}_mb", mb["peak_mb"] - mb["floor_mb"], "MB", 1)
    return _ordered(rows, config)


def _ordered(rows: list[Row], config: BenchConfig) -> list[Row]:
    """Method order as given, measurements in the order measured."""
    order = {m: i for i, m in enumerate((ENV_ONLY, *config.methods))}
    return sorted(rows, key=lambda r: order[r.method])


def run_benchmark(config: BenchConfig, out_dir: str | Path = "results/bench") -> tuple[list[Row], str]:
    """Measure every env in `config`, write bench.csv and bench.md to `out_dir`; return rows and Markdown."""
    th.set_num_threads(config.threads)
    load_start = os.getloadavg()[0]
    started = time.perf_counter()
    rows: list[Row] = []
    for env_id in config.envs:
        rows += bench_env(config, env_id)
    context = dict(torch_threads=th.get_num_threads(), machine=machine_line(), load_avg_1m=round(load_start, 2))
    rows = with_ratios([replace(r, **context) for r in rows])
    header = (f"Machine: {context['machine']}. Torch threads: {context['torch_threads']}. "
              f"Load average (1 min) before the run {load_start:.2f} (above ~0: other processes shared the CPUs, "
              f"absolute numbers are disturbed, ratios less so). Took {time.perf_counter() - started:.0f} s.")
    _, _, markdown = write_outputs(rows, out_dir, header)
    return rows, markdown
