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
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS), help="env ids with paper settings")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), help="must include baseline")
    parser.add_argument("--train-steps", type=int, default=None,
                        help="measured env steps per method, rounded up to whole PPO iterations "
                             "(default: 12288 MuJoCo, 4096 Atari; --quick: 1024, 512)")
    parser.add_argument("--repeats", type=int, default=None, help="timing samples per inference measurement (5; --quick 3)")
    parser.add_argument("--states", type=int, default=None, help="states scored in the large-batch timings (4096; --quick 256)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--out", default="results/bench", help="folder for bench.csv and bench.md")
    parser.add_argument("--quick", action="store_true",
                        help="~1 minute: short rollouts, 256 states, 3 repeats, no memory children")
    parser.add_argument("--memory", action=argparse.BooleanOptionalAction, default=None,
                        help="measure peak memory in fresh child processes (default: yes; --quick: no)")
    parser.add_argument("--limits", action=argparse.BooleanOptionalAction, default=True,
                        help="time each inference measurement's arithmetic limit (default: yes)")
    parser.add_argument("--paper-widths", action="store_true",
                        help="the paper's widths per method (384 for Masksembles on HalfCheetah) instead of equal ones")
    parser.add_argument("--set", type=_setting, action="append", default=[], metavar="KEY=VALUE",
                        help="override a PPO setting for every env, e.g. --set n_steps=64")
    args = parser.parse_args(argv)
    given = dict(envs=tuple(args.envs), methods=tuple(args.methods), train_steps=args.train_steps,
                 threads=args.threads, paper_widths=args.paper_widths, limits=args.limits, overrides=dict(args.set))
    for key, value in (("repeats", args.repeats), ("n_states", args.states), ("memory", args.memory)):
        if value is not None:  # given: it wins over the --quick preset
            given[key] = value
    return (quick_config(**given) if args.quick else BenchConfig(**given)), args.out


def main(argv: list[str] | None = None) -> None:
    config, out = parse_args(argv)
    _, markdown = run_benchmark(config, out)
    print(markdown)


if __name__ == "__main__":
    main()
