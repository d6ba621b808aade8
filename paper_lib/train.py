"""Train one (env, method, seed) run and write its checkpoint folder, all or nothing.

The folder holds model.zip (SB3, loads with plain PPO.load), vecnormalize.pkl when the env
normalizes observations, training_curve.csv, and config.json (the resolved config, package
versions and machine). It is written into a temporary sibling and renamed into place only
when everything succeeded, so an interrupted run never leaves a half-written checkpoint.

    python -m paper_lib.train HalfCheetah-v5 masksembles 0 results/checkpoints/HalfCheetah-v5/masksembles/seed0
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from paper_lib.agents import make_agent
from paper_lib.provenance import machine, package_versions


class TrainingCurve(BaseCallback):
    """Per rollout: mean training-episode return (sampled actions, Monitor's last 100 episodes)."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[dict[str, float]] = []
        self.start = time.perf_counter()

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        episodes = self.model.ep_info_buffer
        self.rows.append({
            "timesteps": self.num_timesteps,
            "reward": float(np.mean([e["r"] for e in episodes])) if episodes else float("nan"),
            "episode_length": float(np.mean([e["l"] for e in episodes])) if episodes else float("nan"),
            # mean reward per env step of this rollout: defined even before any episode has ended
            "step_reward": float(np.mean(self.model.rollout_buffer.rewards)),
            "wall_seconds": time.perf_counter() - self.start,
        })


def train_run(env_id: str, method: str, seed: int, out_dir: str | Path, algo: str = "ppo",
              total_timesteps: int | None = None, agent_kwargs: dict[str, Any] | None = None,
              torch_threads: int = 1, progress_bar: bool = False) -> Path:
    """Train and write the checkpoint folder `out_dir` (replacing an old one only on success)."""
    th.set_num_threads(torch_threads)
    out_dir = Path(out_dir)
    model = make_agent(algo, method, env_id, seed, **(agent_kwargs or {}))
    steps = int(total_timesteps if total_timesteps is not None else model.paper_lib_config["total_timesteps"])
    curve = TrainingCurve()
    started = time.perf_counter()
    model.learn(steps, callback=curve, progress_bar=progress_bar)
    config = {**model.paper_lib_config, "total_timesteps": steps, "wall_seconds": time.perf_counter() - started,
              "torch_threads": torch_threads, "versions": package_versions(), "machine": machine()}

    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    tmp.chmod(0o755)
    try:
        model.save(tmp / "model.zip")
        normalizer = model.get_vec_normalize_env()
        if normalizer is not None:
            normalizer.save(str(tmp / "vecnormalize.pkl"))
        pd.DataFrame(curve.rows).to_csv(tmp / "training_curve.csv", index=False)
        (tmp / "config.json").write_text(json.dumps(config, indent=2, sort_keys=True, default=str))
        if out_dir.exists():
            shutil.rmtree(out_dir)
        tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("env_id")
    parser.add_argument("method")
    parser.add_argument("seed", type=int)
    parser.add_argument("out_dir")
    parser.add_argument("--algo", default="ppo")
    parser.add_argument("--timesteps", type=int, default=None)
    parser.add_argument("--assignment", default="shared")
    parser.add_argument("--progress-bar", action="store_true")
    args = parser.parse_args()
    train_run(args.env_id, args.method, args.seed, args.out_dir, algo=args.algo, total_timesteps=args.timesteps,
              agent_kwargs={"assignment": args.assignment}, progress_bar=args.progress_bar)


if __name__ == "__main__":
    main()
