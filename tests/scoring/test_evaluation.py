"""Reward evaluation (paper Table 1): which action modes each env is played with."""

from __future__ import annotations

from pathlib import Path

import pytest

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.agents.factory import make_agent
from paper_lib.scoring.rewards import evaluate_rewards


@pytest.mark.parametrize(("env_id", "modes"), [("BerzerkNoFrameskip-v4", [False]),
                                               ("HalfCheetah-v5", [True, False])])
def test_berzerk_is_evaluated_with_sampled_actions_only(env_id, modes, tiny_overrides, tmp_path: Path):
    # the paper: a deterministic Berzerk agent gets stuck, so its Table 1 cells are sampled only
    one_env = {**tiny_overrides, "batch_size": 16}  # 16 steps a rollout with one env: no truncated minibatch
    model = make_agent("ppo", "baseline", env_id, seed=0, n_envs=1, overrides=one_env)
    checkpoint = Checkpoint(model, {"env_id": env_id, "method": "baseline"}, None, tmp_path)
    episodes = evaluate_rewards(checkpoint, episodes=1, seed=0)
    assert sorted(episodes["deterministic"].unique(), reverse=True) == modes
    assert (episodes["length"] > 0).all()
    if env_id.startswith("Berzerk"):
        # RAM 92 counts rooms, +1 after each death too: a whole game of three lives gets past 1
        assert episodes["source_indicator_max"].min() >= 3
    else:
        assert "source_indicator_max" not in episodes
