"""The command line of a per-run stage module: `python -m <module> ENV METHOD SEED [--params params.yaml]`."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from paper_lib.pipeline.config import RunConfig, load_run_config


def run_stage_main(argv: list[str] | None, description: str,
                   stage: Callable[[RunConfig, str, str, int, str], Path]) -> None:
    """Parse one run of the profile, call ``stage(cfg, env, method, seed, params path)`` and print what it wrote;
    a bad input (not a run of the profile, a missing or wrong file) is one line and exit status 2, no traceback."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("env_id")
    parser.add_argument("method")
    parser.add_argument("seed", type=int)
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args(argv)
    try:
        cfg = load_run_config(args.params)
        if (args.env_id, args.method, args.seed) not in cfg.runs():
            raise ValueError(f"{args.env_id} {args.method} seed {args.seed} is not a run of profile {cfg.profile!r}")
        print(stage(cfg, args.env_id, args.method, args.seed, args.params))
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")
