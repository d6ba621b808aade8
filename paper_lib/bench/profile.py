"""Where one PPO update's (or one inference call's) time goes, per method (torch.profiler, CPU).

    python -m paper_lib.bench.profile --env HalfCheetah-v5 --methods baseline masksembles mc_dropconnect
    python -m paper_lib.bench.profile --inference act --states 1 --methods baseline masksembles mc_dropout

Builds each method with the benchmark's equal widths. Update: runs one warm-up iteration and
one more rollout, then profiles `model.train()` on it and prints the ops with the largest
total time, in ms per gradient step. --inference predict|act|uncertainty: profiles that call
(`model.predict`, `act_with_uncertainty`, `uncertainty`) on --states random observations,
in ms per call (a baseline's "act" is predict plus its discrete measures, as the benchmark
times it). Comparable across methods; absolute values are as noisy as the machine.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch as th
from torch.profiler import ProfilerActivity, profile

from paper_lib.bench.config import BenchConfig
from paper_lib.bench.models import build_model, has_measures
from paper_lib.measures.estimates import act_with_uncertainty, uncertainty
from paper_lib.methods.policy import MemberActorCriticPolicy

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
    return _table(prof.key_averages(), steps, f"{env_id} {method}", "gradient step", top)


INFERENCE_CALLS = ("predict", "act", "uncertainty")


def _inference_call(model, method: str, what: str, states: np.ndarray):
    """The benchmark's call for `what` (see run._inference_fns), as a function of nothing."""
    if what == "predict" or (what == "act" and not has_measures(model, method)):
        return lambda: model.predict(states, deterministic=True)
    if what == "uncertainty":
        return lambda: uncertainty(model.policy, states, path="fast")
    if isinstance(model.policy, MemberActorCriticPolicy):
        return lambda: act_with_uncertainty(model.policy, states)
    return lambda: (model.predict(states, deterministic=True), uncertainty(model.policy, states, path="fast"))


def profile_inference(config: BenchConfig, env_id: str, method: str, what: str, n_states: int, top: int = 15) -> str:
    """A text table of the `top` ops of `what` on `n_states` random observations, in ms per call."""
    model = build_model(config, env_id, method)
    space = model.observation_space
    states = np.stack([space.sample() for _ in range(n_states)])
    call = _inference_call(model, method, what, states)
    for _ in range(3):  # warm-up
        call()
    calls = max(3, 2000 // n_states)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(calls):
            call()
    return _table(prof.key_averages(), calls, f"{env_id} {method}: {what} on {n_states} states", "call", top)


def _table(events, per: int, title: str, unit: str, top: int) -> str:
    total_ms = sum(e.self_cpu_time_total for e in events) / 1e3 / per
    lines = [f"== {title}: {total_ms:.3f} ms per {unit} ({per} profiled)",
             f"{'op':58s} {'total':>8s} {'self':>8s} {'calls':>6s}   (ms and calls per {unit})"]
    for e in sorted(events, key=lambda e: -e.cpu_time_total)[:top]:
        lines.append(f"{e.key[:58]:58s} {e.cpu_time_total / 1e3 / per:8.3f} {e.self_cpu_time_total / 1e3 / per:8.3f} "
                     f"{e.count / per:6.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m paper_lib.bench.profile", description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="HalfCheetah-v5")
    parser.add_argument("--methods", nargs="+", default=["baseline", "masksembles", "mc_dropconnect"])
    parser.add_argument("--top", type=int, default=15)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--inference", choices=INFERENCE_CALLS, default=None,
                        help="profile this inference call instead of an update")
    parser.add_argument("--states", type=int, default=1, help="observations per inference call")
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    config = BenchConfig(envs=(args.env,), methods=("baseline", *[m for m in args.methods if m != "baseline"]),
                         overrides=dict(SMALL_UPDATE), threads=args.threads)
    for method in args.methods:
        if args.inference is None:
            print(profile_update(config, args.env, method, args.top), flush=True)
        else:
            print(profile_inference(config, args.env, method, args.inference, args.states, args.top), flush=True)


if __name__ == "__main__":
    main()
