"""Aggregates across envs as rliable defines them: IQM, stratified bootstrap, probability of improvement."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from paper_lib.reporting.aggregates import (aggregate_table, improvement_table, interquartile_mean, normalized_rewards,
                                            performance_profile, probability_of_improvement, profile_taus,
                                            profiles_by_env_family, score_distribution, score_matrices)
from paper_lib.scoring.statistics import stratified_resample


def test_interquartile_mean_is_the_mean_of_the_middle_half_of_all_runs():
    assert interquartile_mean(np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 100.0]])) == pytest.approx(4.5)


def test_probability_of_improvement_counts_pairs_per_env_ties_half_then_averages_envs():
    x = np.array([[1.0, 2.0], [3.0, 2.0]])  # env 0: runs 1, 3; env 1: runs 2, 2
    y = np.array([[2.0, 2.0], [2.0, 2.0]])
    assert probability_of_improvement(x, y) == pytest.approx((0.5 + 0.5) / 2)  # env 0: 1 of 2 pairs; env 1: all ties
    assert probability_of_improvement(y + 10, y) == 1.0 and probability_of_improvement(y, y + 10) == 0.0


def test_the_bootstrap_resamples_each_env_apart():
    """Each env keeps its weight: an env's resampled runs are its own, so envs of different scale never mix."""
    matrix = np.array([[0.0, 100.0], [1.0, 101.0], [2.0, 102.0]])
    for _ in range(50):
        resampled = stratified_resample(matrix, np.random.default_rng(_))
        assert set(resampled[:, 0]) <= {0.0, 1.0, 2.0} and set(resampled[:, 1]) <= {100.0, 101.0, 102.0}
    flat = {"a": np.array([[0.0, 100.0], [0.0, 100.0], [0.0, 100.0]])}  # pooled resampling would move the mean
    table = aggregate_table(flat, n_boot=200).iloc[0]
    assert table["mean"] == table["mean_low"] == table["mean_high"] == 50.0


def test_intervals_hold_the_estimate_repeat_exactly_and_pairs_need_both_methods():
    rng = np.random.default_rng(0)
    matrices = {"masksembles": rng.normal(1.0, 0.3, (3, 4)), "mc_dropout": rng.normal(0.5, 0.3, (3, 4))}
    table = aggregate_table(matrices, n_boot=500, seed=3)
    assert table.equals(aggregate_table(matrices, n_boot=500, seed=3))
    assert (table["iqm_low"] <= table["iqm"]).all() and (table["iqm"] <= table["iqm_high"]).all()
    assert (table["mean_low"] <= table["mean"]).all() and (table["mean"] <= table["mean_high"]).all()
    improvement = improvement_table(matrices, n_boot=500)
    assert improvement[["method", "over"]].values.tolist() == [["masksembles", "mc_dropout"]]  # the others lack runs
    row = improvement.iloc[0]
    assert row["ci_low"] <= row["probability"] <= row["ci_high"] and row["probability"] > 0.5


def test_score_matrices_keep_the_envs_where_every_method_has_the_same_seeds():
    rows = [{"env": env, "method": m, "seed": s, "v": float(10 * i + s)}
            for i, env in enumerate(["A", "B"]) for m in ("x", "y") for s in (0, 1, 2)]
    rows = [r for r in rows if not (r["env"] == "B" and r["method"] == "y" and r["seed"] == 2)]  # B lacks y's seed 2
    matrices = score_matrices(pd.DataFrame(rows), "v", ["x", "y"])
    assert matrices["x"].tolist() == [[0.0], [1.0], [2.0]] and matrices["y"].shape == (3, 1)


def test_rewards_are_normalized_by_the_baseline_of_their_env_with_sampled_actions():
    episodes = pd.DataFrame([
        {"env": "E", "method": "baseline", "seed": 0, "inference": "single", "deterministic": False, "reward": 100.0},
        {"env": "E", "method": "baseline", "seed": 1, "inference": "single", "deterministic": False, "reward": 300.0},
        {"env": "E", "method": "masksembles", "seed": 0, "inference": "combined", "deterministic": False, "reward": 100.0},
        {"env": "E", "method": "masksembles", "seed": 0, "inference": "single", "deterministic": False, "reward": 900.0},
        {"env": "E", "method": "masksembles", "seed": 0, "inference": "combined", "deterministic": True, "reward": 900.0},
    ])
    runs = normalized_rewards(episodes).set_index(["method", "seed"])["normalized_reward"]
    assert runs[("baseline", 0)] == 0.5 and runs[("baseline", 1)] == 1.5 and runs[("masksembles", 0)] == 0.5


def test_score_distribution_is_the_fraction_of_all_runs_strictly_above_tau():
    matrix = np.array([[0.2, 0.9], [0.6, 0.4]])  # 2 seeds x 2 envs
    assert score_distribution(matrix, np.array([0.0, 0.5, 0.9, 1.0])).tolist() == [1.0, 0.5, 0.0, 0.0]


def test_performance_profile_bands_resample_each_env_apart_and_need_two_seeds():
    """Env A's runs all score 0, env B's all 1: a stratified resample keeps half the runs above 0.5 every time
    (a pooled one would not), so the band there is exactly 0.5; one seed per env gives no band at all."""
    split = {"m": np.array([[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])}
    taus = np.array([-0.5, 0.5, 1.5])
    profile = performance_profile(split, taus, n_boot=200)
    assert profile["fraction"].tolist() == [1.0, 0.5, 0.0]
    assert profile["fraction_low"].tolist() == profile["fraction_high"].tolist() == [1.0, 0.5, 0.0]
    rng = np.random.default_rng(0)
    spread = {"better": rng.uniform(0.6, 1.0, (3, 4)), "worse": rng.uniform(0.0, 0.5, (3, 4))}
    grid = profile_taus(spread)
    curves = performance_profile(spread, grid, n_boot=300, seed=1)
    assert curves.equals(performance_profile(spread, grid, n_boot=300, seed=1))  # seeded per method
    for _, curve in curves.groupby("method"):
        assert (np.diff(curve["fraction"]) <= 0).all()  # a profile only falls as tau rises
        assert (curve["fraction_low"] <= curve["fraction"]).all() and (curve["fraction"] <= curve["fraction_high"]).all()
    by = curves.set_index(["method", "tau"])["fraction"]
    assert (by["better"] >= by["worse"]).all() and grid[0] < spread["worse"].min() and grid[-1] == spread["better"].max()
    assert by["worse"].iloc[0] == 1.0 and by["better"].iloc[-1] == 0.0  # every curve runs from 1 down to 0
    one_seed = performance_profile({"m": spread["better"][:1]}, grid, n_boot=50)
    assert one_seed["fraction_low"].isna().all() and one_seed["fraction"].notna().all()


def test_profiles_by_env_family_keep_mujoco_and_atari_apart():
    rows = [{"env": env, "method": m, "seed": s, "auroc": base + 0.1 * s + (0.2 if m == "x" else 0.0)}
            for env, base, seeds in (("HalfCheetah-v5", 0.3, (0, 1)), ("MsPacmanNoFrameskip-v4", 0.5, (0,)))
            for m in ("x", "y") for s in seeds]
    profiles = profiles_by_env_family(pd.DataFrame(rows), "auroc", ["x", "y"], n_boot=50)
    assert set(profiles["family"]) == {"MuJoCo", "Atari"}
    atari, mujoco = (profiles[profiles["family"] == f] for f in ("Atari", "MuJoCo"))
    assert atari["fraction_low"].isna().all() and mujoco["fraction_low"].notna().all()  # one seed per env: no band
    assert atari["tau"].max() == pytest.approx(0.7) and mujoco["tau"].max() == pytest.approx(0.6)  # each its own range
    assert 0.49 < atari["tau"].min() < 0.5 and 0.29 < mujoco["tau"].min() < 0.3
    assert (mujoco["envs"] == "HalfCheetah-v5").all() and (atari["seeds_per_env"] == 1).all()
