"""Reward evaluation (paper Table 1): combined and single-member inference, deterministic and sampled.

Single-member rows: each of the k members plays its share of the episodes (member m plays
episodes m, m+k, ...), so every member is represented and the row averages over members.
Berzerk is played with sampled actions only, as in the paper (`action_modes`).

Atari rows also record `source_indicator_max`: the highest value of the game's default OOD
source's indicator (e.g. Seaquest's level counter) over the whole game. The ID states of the OOD
benchmark cover only the start of episodes; these full games show whether the trained agent
reaches the OOD source's values by itself (`paper_lib.ood.play_coverage`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.agents.envs import is_atari
from paper_lib.methods.policy import MemberActorCriticPolicy
from paper_lib.scoring.statistics import seed_mean_std

#: Envs evaluated with sampled actions only. The paper: Berzerk "can only be sampled", since a
#: deterministic agent gets stuck there, and each stuck episode would run to the 27,000-step limit
#: (108,000 frames) and say nothing about the agent.
SAMPLED_ONLY_ENVS: frozenset[str] = frozenset({"BerzerkNoFrameskip-v4"})


def action_modes(env_id: str) -> tuple[bool, ...]:
    """The `deterministic` values an env is evaluated with: both, or sampled only (`SAMPLED_ONLY_ENVS`)."""
    return (False,) if env_id in SAMPLED_ONLY_ENVS else (True, False)


def evaluate_rewards(checkpoint: Checkpoint, episodes: int, seed: int) -> pd.DataFrame:
    """One row per episode: inference (combined/single), deterministic, member, reward, length."""
    policy = checkpoint.model.policy
    rows = []
    has_members = isinstance(policy, MemberActorCriticPolicy)
    saved = policy.inference if has_members else None
    try:
        for deterministic in action_modes(checkpoint.config["env_id"]):
            for inference in (("combined", "single") if has_members else ("single",)):
                rows += _episodes(checkpoint, policy, inference, deterministic, episodes, seed, has_members)
    finally:
        if has_members:
            policy.set_inference(*saved)
    return pd.DataFrame(rows)


def _episodes(checkpoint: Checkpoint, policy, inference: str, deterministic: bool, episodes: int, seed: int,
              has_members: bool) -> list[dict]:
    rows = []
    plan = [(None, episodes)] if inference == "combined" or not has_members else [
        (m, len(range(m, episodes, policy.n_members))) for m in range(policy.n_members)]
    for member, n in plan:
        if n == 0:
            continue
        if has_members:
            policy.set_inference(checkpoint.config.get("inference", "vote") if member is None else "single", member)
        env = checkpoint.env(1, seed + (member or 0) * 1000)
        tracker = IndicatorMaximum(env, checkpoint.config["env_id"]) if is_atari(checkpoint.config["env_id"]) else None
        rewards, lengths = evaluate_policy(checkpoint.model, env, n_eval_episodes=n, deterministic=deterministic,
                                           return_episode_rewards=True, callback=tracker)
        env.close()
        extra = [{"source_indicator_max": m} for m in tracker.maxima] if tracker else [{}] * len(rewards)
        rows += [{"inference": inference, "deterministic": deterministic, "member": member, "reward": float(r),
                  "length": int(l), **x} for r, l, x in zip(rewards, lengths, extra)]
    return rows


class IndicatorMaximum:
    """`evaluate_policy` callback: per finished game, the highest value of the default OOD source's indicator.

    Read after every step of the single env; a game counts as finished where `evaluate_policy`
    counts it (Monitor's "episode" info, i.e. the game over, not a lost life).
    """

    def __init__(self, venv: VecEnv, env_id: str) -> None:
        from paper_lib.ood.atari import DEFAULT_SOURCE, game_of, read_indicator

        if venv.num_envs != 1:
            raise ValueError(f"IndicatorMaximum reads one env, got {venv.num_envs}.")
        game = game_of(env_id)
        env = venv.unwrapped.envs[0]
        self._read = lambda: read_indicator(env, game, DEFAULT_SOURCE[game])
        self.maxima: list[int] = []
        self._current: int | None = None  # no read before evaluate_policy's first reset

    def __call__(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        info = locals_["info"]
        if locals_["done"] and "episode" in info:
            # the game's last state is gone (the env was reset): its value was read a step before
            self.maxima.append(self._read() if self._current is None else self._current)
            self._current = None
        else:
            value = self._read()
            self._current = value if self._current is None else max(self._current, value)


def summarize_rewards(df: pd.DataFrame) -> pd.DataFrame:
    """Mean and std per env, method, inference and action mode (Table 1's cells).

    With several seeds: the mean over seeds of each seed's episode mean, and the std across
    seeds (the paper's Table 1; `statistics.seed_mean_std`). With one seed: the std is over
    episodes, and `std_over` says so.
    """
    keys = [c for c in ("env", "method", "inference", "deterministic") if c in df.columns]
    out = seed_mean_std(df, keys, "reward").rename(columns={"row_std": "episode_std", "n_rows": "n_episodes"})
    single_seed = out["n_seeds"] < 2
    out.loc[single_seed, "std"] = out.loc[single_seed, "episode_std"]
    out["std_over"] = np.where(single_seed, "episodes", "seeds")
    return out.drop(columns="episode_std")
