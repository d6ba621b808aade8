"""The spawn analysis: uncertainty and floor contact from reset, on real MuJoCo envs with small real agents."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

from conftest import TINY
from paper_lib import make_agent
from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.experiments.spawn import (ROLLOUT_COLUMNS, floor_contacts, relative_uncertainty, spawn_reading, spawn_rollouts,
                             spawn_summary, spawn_table)


def _run(env_id: str, method: str, tmp_path: Path) -> Checkpoint:
    model = make_agent("ppo", method, env_id, seed=0, n_envs=4, overrides=dict(TINY))  # untrained: it falls over
    return Checkpoint(model=model, config={"env_id": env_id, "method": method}, vecnormalize_path=None, folder=tmp_path)


@pytest.fixture(scope="module")
def walker(tmp_path_factory) -> Checkpoint:
    return _run("Walker2d-v5", "masksembles", tmp_path_factory.mktemp("walker"))


def test_walker_is_spawned_in_the_air_and_every_step_is_scored(walker):
    rows = spawn_rollouts(walker, episodes=2, steps=30, seed=3)
    assert list(rows.columns) == list(ROLLOUT_COLUMNS)
    first = rows[rows.step == 0]
    assert len(first) == 2 and first.airborne.all()  # Walker2d starts 1.25 m up and falls onto the floor
    assert not rows.airborne.all()  # ... and lands within 30 steps
    assert (rows.airborne == (rows.floor_contacts == 0)).all()
    assert (rows.value_std > 0).all() and (rows.policy_std > 0).all()
    pd.testing.assert_frame_equal(rows, spawn_rollouts(walker, episodes=2, steps=30, seed=3))  # same seed, same rows


def test_floor_contacts_counts_contacts_with_the_floor_only():
    cheetah = gym.make("HalfCheetah-v5")
    cheetah.reset(seed=0)
    assert floor_contacts(cheetah) >= 1  # HalfCheetah starts on the floor
    with pytest.raises(ValueError, match="no geom named 'floor'"):
        reacher = gym.make("Reacher-v5")
        reacher.reset(seed=0)
        floor_contacts(reacher)


def test_summary_ratios_and_auroc_against_a_hand_computed_case():
    # value_std is 3 in the air (steps 0-1) and 1 on the floor; policy_std does not care
    rollouts = pd.DataFrame({"env": "Ant-v5", "method": "masksembles", "seed": 0, "episode": 0, "step": np.arange(6),
                             "value_std": [3.0, 3.0, 1.0, 1.0, 1.0, 1.0], "policy_std": 1.0,
                             "floor_contacts": [0, 0, 2, 1, 1, 3]}).assign(airborne=lambda d: d.floor_contacts == 0)
    summary = spawn_summary(rollouts, spawn_steps=3).iloc[0]
    assert summary.value_std_spawn_ratio == pytest.approx((7 / 3) / 1.0)
    assert summary.value_std_airborne_auroc == 1.0 and summary.policy_std_airborne_auroc == 0.5
    assert summary.airborne_share_spawn == pytest.approx(2 / 3) and summary.airborne_share_later == 0.0
    assert relative_uncertainty(rollouts, "value_std", 3).tolist() == [3.0, 3.0, 1.0, 1.0, 1.0, 1.0]
    table = spawn_table(spawn_summary(rollouts, 3))
    assert table.seeds.tolist() == [1]
    (line,) = spawn_reading(table)
    assert "Ant-v5" in line and "masksembles 2.33" in line and "above 0.5 for 1 of 1" in line


def test_bad_inputs_raise_one_clear_error(tmp_path):
    with pytest.raises(ValueError, match="needs a MuJoCo member-method run"):
        spawn_rollouts(_run("HalfCheetah-v5", "baseline", tmp_path), episodes=1, steps=2)
    with pytest.raises(ValueError, match="episodes=0"):
        spawn_rollouts(_run("HalfCheetah-v5", "mc_dropout", tmp_path), episodes=0, steps=2)
