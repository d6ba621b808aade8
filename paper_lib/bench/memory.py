"""Peak memory: the peak resident set size (RSS) of a fresh process, per (env, method, phase).

Why RSS: tracemalloc sees neither torch's nor numpy's C allocations, and the torch profiler
sees torch tensors only, not the rollout buffer (numpy) nor the envs. RSS sees everything
the OS had to provide. It is a per-process high-water mark, so each (env, method, phase)
runs in its own child process, which measures

    floor = RSS once imports, the env and the input states exist (before the model is built)
    peak  = peak RSS after the phase (train: build + one PPO iteration; infer: build, then
            predict on and score n_states random observations: values do not change memory)

and the benchmark reports the peak and the increase `peak - floor`, the model's own share.

On Linux the peak is VmHWM from /proc/self/status, not getrusage's ru_maxrss: ru_maxrss
survives fork + exec, so a child of a parent holding 800 MB of Atari models reports 800 MB
whatever it does. Imports also leave a transient peak above the floor, so the child resets
VmHWM at the floor (`echo 5 > /proc/self/clear_refs`); a model smaller than that transient
still shows. Elsewhere it falls back to ru_maxrss (increases then read 0 below the import
transient). Memory does not depend on CPU contention, so children run `memory_jobs` at a time.

A child by hand (what the parent runs):
    python -c "from paper_lib.bench.memory import child_main; child_main()" \\
        '{"env_id": "CartPole-v1", "method": "ensemble", "phase": "train", "config": {"envs": ["CartPole-v1"]}}'
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from typing import Any

import numpy as np
import torch as th

from paper_lib.bench.config import BenchConfig
from paper_lib.bench.models import build_model, has_measures, make_bench_env
from paper_lib.measures.estimates import uncertainty

PHASES = ("train", "infer")
# Not `-m paper_lib.bench.memory`: the package imports this module first, and runpy warns.
_CHILD = "from paper_lib.bench.memory import child_main; child_main()"


def _status_mb(field: str) -> float | None:
    """A memory field of /proc/self/status in MB (Linux), or None where there is none."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith(field + ":")) / 1024
    except (OSError, StopIteration, ValueError):
        return None


def _peak_rss_mb() -> float:
    peak = _status_mb("VmHWM")
    return peak if peak is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB


def _floor_rss_mb() -> float:
    """Current RSS, with the high-water mark reset to it (Linux); else the high-water mark so far."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return _peak_rss_mb()
    current = _status_mb("VmRSS")
    return current if current is not None else _peak_rss_mb()


def measure_in_this_process(spec: dict[str, Any]) -> dict[str, float]:
    """Run one phase here and return {"floor_mb", "peak_mb"}: call only in a fresh process."""
    config = BenchConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in spec["config"].items()})
    th.set_num_threads(config.threads)
    env_id, method, phase = spec["env_id"], spec["method"], spec["phase"]
    env = make_bench_env(config, env_id)
    states = None if phase == "train" else np.stack([env.observation_space.sample() for _ in range(config.n_states)])
    floor = _floor_rss_mb()
    model = build_model(config, env_id, method, env)
    if phase == "train":
        model.learn(model.n_steps * model.n_envs)
    else:
        model.predict(states, deterministic=True)
        if has_measures(model, method):
            uncertainty(model.policy, states, path="fast")
    return {"floor_mb": floor, "peak_mb": _peak_rss_mb()}


def measure_in_child(config: BenchConfig, env_id: str, method: str, phase: str) -> dict[str, float]:
    """Run one phase in a fresh Python process and return its {"floor_mb", "peak_mb"}."""
    spec = {"config": asdict(config), "env_id": env_id, "method": method, "phase": phase}
    done = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(spec)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"memory child for {env_id}/{method}/{phase} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def measure_all(config: BenchConfig, env_id: str) -> dict[tuple[str, str], dict[str, float]]:
    """Every (method, phase) of `env_id`, `config.memory_jobs` children at a time."""
    keys = [(method, phase) for method in config.methods for phase in PHASES]
    with ThreadPoolExecutor(max_workers=max(1, config.memory_jobs)) as pool:
        results = pool.map(lambda key: measure_in_child(config, env_id, *key), keys)
        return dict(zip(keys, results))


def child_main() -> None:
    """Entry point of a child: the spec as JSON in argv[1], the result as JSON on stdout's last line."""
    print(json.dumps(measure_in_this_process(json.loads(sys.argv[1]))))
