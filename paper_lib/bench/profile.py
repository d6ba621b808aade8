"""Where one PPO update's time goes, per method (torch.profiler, CPU).

    python -m paper_lib.bench.profile --env HalfCheetah-v5 --methods baseline masksembles mc_dropconnect

Builds each method with the benchmark's equal widths, runs one warm-up iteration and one
more rollout, then profiles `model.train()` on it and prints the ops with the largest
total time, in ms per gradient step (comparable across methods; absolute values are as
noisy as the machine).
"""

from __future__ import annotations

import argparse

import torch as th
from torch.profiler import ProfilerActivity, profile

from paper_lib.bench.config import BenchConfig
from paper_lib.bench.models import build_model

#: Small but real: 512 samples, the paper's batch of 64, two epochs = 16 gradient steps.
SMALL_UPDATE = {"n_steps": 64, "n_epochs": 2}


def profile_update(config: BenchConfig, env_id: str, method: str, top: int = 15) -> str:
    """A text table of the `top` ops of one profiled update of `method`, in ms per gradient step."""
    model = build_model(config, env_id, method)
    rollout = model.n_steps * model.n_envs
    model.learn(rollout)  # warm-up iteration
    model.learn(rollout, reset_num_timesteps=False)  # fills the buffer the profiled update reads
    steps = model.n_epochs * (rollout // model.batch_size)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        model.train()
    events = prof.key_averages()
    total_ms = sum(e.self_cpu_time_total for e in events) / 1e3 / steps
    lines = [f"== {env_id} {method}: {total_ms:.2f} ms per gradient step ({steps} steps profiled)",
             f"{'op':58s} {'total':>8s} {'self':>8s} {'calls':>6s}   (ms and calls per gradient step)"]
    for e in sorted(events, key=lambda e: -e.cpu_time_total)[:top]:
        lines.append(f"{e.key[:58]:58s} {e.cpu_time_total / 1e3 / steps:8.3f} {e.self_cpu_time_total / 1e3 / steps:8.3f} "
                     f"{e.count / steps:6.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m paper_lib.bench.profile", description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="HalfCheetah-v5")
    parser.add_argument("--methods", nargs="+", default=["baseline", "masksembles", "mc_dropconnect"])
    parser.add_argument("--top", type=int, default=15)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    config = BenchConfig(envs=(args.env,), methods=("baseline", *[m for m in args.methods if m != "baseline"]),
                         overrides=dict(SMALL_UPDATE), threads=args.threads)
    for method in args.methods:
        print(profile_update(config, args.env, method, args.top), flush=True)


if __name__ == "__main__":
    main()
