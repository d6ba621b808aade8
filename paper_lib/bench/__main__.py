"""`python -m paper_lib.bench`: the command line of the cost benchmark (see the package docstring)."""

from __future__ import annotations

import argparse
from typing import Any

import yaml

from paper_lib.bench.config import DEFAULT_ENVS, BenchConfig, quick_config
from paper_lib.bench.run import run_benchmark
from paper_lib.methods.networks import METHODS


def _setting(text: str) -> tuple[str, Any]:
    """KEY=VALUE with a YAML value, so numbers come out as numbers."""
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"--set takes KEY=VALUE, got {text!r}")
    return key, yaml.safe_load(value)


def parse_args(argv: list[str] | None = None) -> tuple[BenchConfig, str]:
    parser = argparse.ArgumentParser(prog="python -m paper_lib.bench",
                                     description="What uncertainty costs, against plain SB3 PPO with the same network sizes.")
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS))
    parser.add_argument("--methods", nargs="+", default=list(METHODS), help="must include baseline")
    parser.add_argument("--train-steps", type=int, default=None,
                        help="measured env steps per method, rounded up to whole PPO iterations "
                             "(default: 8192 MuJoCo, 3072 Atari; --quick: 1024, 512)")
    parser.add_argument("--repeats", type=int, default=None, help="timing samples per inference measurement (5; --quick 3)")
    parser.add_argument("--states", type=int, default=None, help="states scored in the large-batch timings (4096; --quick 256)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--out", default="results/bench")
    parser.add_argument("--quick", action="store_true", help="~1-2 minutes: short rollouts, 256 states, 3 repeats")
    parser.add_argument("--no-memory", action="store_true", help="skip the peak-memory child processes")
    parser.add_argument("--paper-widths", action="store_true",
                        help="the paper's widths per method (384 for Masksembles on HalfCheetah) instead of equal ones")
    parser.add_argument("--set", type=_setting, action="append", default=[], metavar="KEY=VALUE",
                        help="override a PPO setting for every env, e.g. --set n_steps=64")
    args = parser.parse_args(argv)
    given = dict(envs=tuple(args.envs), methods=tuple(args.methods), train_steps=args.train_steps,
                 threads=args.threads, memory=not args.no_memory, paper_widths=args.paper_widths,
                 overrides=dict(args.set))
    if args.repeats is not None:
        given["repeats"] = args.repeats
    if args.states is not None:
        given["n_states"] = args.states
    return (quick_config(**given) if args.quick else BenchConfig(**given)), args.out


def main(argv: list[str] | None = None) -> None:
    config, out = parse_args(argv)
    _, markdown = run_benchmark(config, out)
    print(markdown)


if __name__ == "__main__":
    main()
