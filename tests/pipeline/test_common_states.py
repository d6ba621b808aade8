"""One state set per comparison (issue 66): member methods scored on the baseline's states of their seed.

Reads the committed results: the common-state scores of Swimmer (no observation normalization, so an
observation detector is the same function for every agent) must share the baseline's own cluster resamples exactly,
which is what makes the differences between methods paired.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from paper_lib.pipeline.common_states import common_scores_dir, for_policy, read_common
from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.layout import common_runs

ROOT = Path(__file__).resolve().parents[2]


def test_only_member_runs_with_a_baseline_of_their_seed_score_common_states():
    runs = [("Swimmer-v5", "baseline", 0), ("Swimmer-v5", "masksembles", 0), ("Swimmer-v5", "masksembles", 3),
            ("Ant-v5", "ensemble", 0)]
    assert common_runs(runs) == [("Swimmer-v5", "masksembles", 0)]


def test_each_policy_sees_the_raw_states_through_its_own_normalizer():
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
    import gymnasium as gym

    from paper_lib.ood.datasets import StateDataset

    states = np.arange(12, dtype=np.float32).reshape(3, 4)
    data = StateDataset(states, [0, 1, 1], ["id", "x", "x"], [-1, 0, 0], [0, 1, 1], [0, 0, 1], configs=["{}"],
                        policy_obs=np.zeros_like(states))
    normalizer = VecNormalize(DummyVecEnv([lambda: gym.make("CartPole-v1")]), norm_reward=False)
    normalizer.obs_rms.mean[:] = 1.0
    normalizer.obs_rms.var[:] = 4.0
    seen = for_policy(data, normalizer)
    assert np.allclose(seen.policy_obs, np.clip((states - 1.0) / np.sqrt(4.0 + 1e-8), -10, 10))
    assert seen.states is data.states or np.array_equal(seen.states, data.states)
    assert for_policy(data, None).policy_obs is None


def test_the_committed_common_scores_share_the_baselines_resamples():
    cfg = load_run_config(ROOT / "params.yaml")
    cfg = cfg.__class__(**{**cfg.__dict__, "root": ROOT})
    run = ("Swimmer-v5", "masksembles", 0)
    metrics, replicates = read_common(cfg, [run])
    assert set(metrics["states"]) == {"common"} and set(metrics["states_of"]) == {"baseline"}
    own = pd.read_csv(cfg.layout.scores_dir("Swimmer-v5", "baseline", 0) / "metrics.csv")
    own_reps = np.load(cfg.layout.scores_dir("Swimmer-v5", "baseline", 0) / "replicates.npy")
    row = own.index[(own.measure == "knn_obs") & (own.ood_set == "perturbed")][0]
    assert np.array_equal(replicates[(*run, "perturbed", "knn_obs")], own_reps[row][~np.isnan(own_reps[row])])


def test_common_scores_made_from_other_files_are_refused(tmp_path):
    cfg = load_run_config(ROOT / "params.yaml")
    cfg = cfg.__class__(**{**cfg.__dict__, "root": ROOT})
    run = ("Swimmer-v5", "masksembles", 0)
    copy = cfg.__class__(**{**cfg.__dict__, "root": tmp_path})
    for source, target in ((common_scores_dir(cfg, *run), common_scores_dir(copy, *run)),
                           (cfg.checkpoint_dir(*run), copy.checkpoint_dir(*run))):
        shutil.copytree(source, target)
    dataset = cfg.dataset_path("Swimmer-v5", "baseline", 0)
    copy.dataset_path("Swimmer-v5", "baseline", 0).parent.mkdir(parents=True)
    shutil.copy(dataset, copy.dataset_path("Swimmer-v5", "baseline", 0))
    read_common(copy, [run])  # the same files: accepted
    record = common_scores_dir(copy, *run) / "provenance.json"
    tampered = json.loads(record.read_text())
    tampered["sha256"]["dataset"] = "0" * 64
    record.write_text(json.dumps(tampered))
    with pytest.raises(ValueError, match="scored from other files"):
        read_common(copy, [run])
    with pytest.raises(FileNotFoundError, match="common_score@Swimmer-v5-masksembles-1"):
        read_common(copy, [("Swimmer-v5", "masksembles", 1)])
