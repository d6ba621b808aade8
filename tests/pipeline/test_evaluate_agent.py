"""Bring your own agent: the benchmark's OOD metrics for SB3 checkpoints that paper_lib did not make."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3 import A2C, PPO

from paper_lib import make_agent, paper_hyperparameters
from paper_lib.agents.envs import make_env
from paper_lib.pipeline.evaluate_agent import Budget, evaluate_agent, main

TINY_BUDGET = Budget(configs=2, steps_per_config=10, id_episodes=4, skip_first=2, max_episode_steps=20,
                     n_bootstrap=20, n_scoring_seeds=2)
DETECTORS = {"knn_obs", "mahalanobis_obs", "knn_features", "mahalanobis_features"}


def test_a_plain_sb3_agent_gets_the_member_free_detectors(tmp_path):
    model = PPO("MlpPolicy", make_env("HalfCheetah-v5", 2, seed=0), n_steps=32, batch_size=32, n_epochs=1, seed=0)
    model.learn(64)
    model.save(tmp_path / "plain.zip")
    result = evaluate_agent(tmp_path / "plain.zip", "HalfCheetah-v5", budget=TINY_BUDGET, out_dir=tmp_path / "out")
    assert set(result.metrics.measure) == DETECTORS  # continuous actions, no members: detectors only
    assert set(result.metrics.ood_set) == {"perturbed", "noise"}
    assert np.isfinite(result.metrics.auroc).all()
    assert (result.metrics.n_ood_clusters[result.metrics.ood_set == "perturbed"] == 2).all()
    assert len(result.dataset) == 60  # 4 ID episodes x 10 + 2 configurations x 10
    for name in ("dataset.npz", "ood_metrics.csv", "ood_metrics.md", "ood_metrics.tex", "roc.csv"):
        assert (tmp_path / "out" / name).is_file(), name
    assert "OpenOOD" in (tmp_path / "out" / "ood_metrics.md").read_text()


def test_cli_on_a_member_policy(tmp_path, capsys):
    model = make_agent("a2c", "mc_dropout", "HalfCheetah-v5", seed=0, overrides={"n_steps": 8},
                       hyperparameters={**paper_hyperparameters("HalfCheetah-v5"), "normalize_obs": False})
    model.learn(64)
    model.save(tmp_path / "members.zip")
    main([str(tmp_path / "members.zip"), "HalfCheetah-v5", "--configs", "2", "--steps", "10", "--id-episodes", "4",
          "--skip-first", "2", "--max-episode-steps", "20", "--bootstrap", "20", "--scoring-seeds", "2",
          "--out", str(tmp_path / "out")])
    printed = capsys.readouterr().out
    assert "value_std" in printed and "knn_obs" in printed and "perturbed" in printed
    metrics = (tmp_path / "out" / "ood_metrics.csv").read_text()
    assert "policy_js" in metrics


def test_bad_inputs_are_one_line(tmp_path, capsys):
    A2C("MlpPolicy", "CartPole-v1", n_steps=8).save(tmp_path / "cartpole.zip")
    with pytest.raises(SystemExit) as exit_info:
        main([str(tmp_path / "cartpole.zip"), "CartPole-v1"])
    assert exit_info.value.code == 2 and "no OOD states exist for 'CartPole-v1'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(tmp_path / "missing.zip"), "HalfCheetah-v5"])
    assert "no model at" in capsys.readouterr().err
    (tmp_path / "junk.zip").write_bytes(b"not a zip")
    with pytest.raises(SystemExit):
        main([str(tmp_path / "junk.zip"), "HalfCheetah-v5"])
    assert "not an SB3 model zip" in capsys.readouterr().err
    with pytest.raises(ValueError, match="id_episodes"):
        Budget(id_episodes=1)
    with pytest.raises(SystemExit):  # a model for another env: its observations do not fit
        main([str(tmp_path / "cartpole.zip"), "HalfCheetah-v5", "--configs", "1", "--steps", "5", "--id-episodes", "2",
              "--skip-first", "1", "--max-episode-steps", "10"])
    assert "observations of shape" in capsys.readouterr().err
