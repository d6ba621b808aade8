"""Aggregates across envs as rliable defines them: IQM, stratified bootstrap, probability of improvement."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from paper_lib.reporting.aggregates import (NORMALIZED_COLUMNS, aggregate_table, by_env_family, improvement_table,
                                            interquartile_mean, normalized_aggregate_table, normalized_rewards,
                                            performance_profile, probability_of_improvement, profile_taus,
                                            profiles_by_env_family, score_distribution, score_matrices)
from paper_lib.scoring.statistics import (cell_rng, percentile_band, ratio_t_interval, stratified_resample,
                                          stratified_resamples, stratified_t_interval)


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


# ------------------------------------------------------------------------------- coverage at our sizes (audit 1, 2)
LOGNORMAL_SIGMA = 0.5  # skewness 1.75: a few runs far above the rest


def _runs(rng: np.random.Generator, kind: str, loc: np.ndarray, scale: np.ndarray, size: tuple[int, ...]) -> np.ndarray:
    """(*size, envs) scores, env e with mean loc[e] and std scale[e]: normal, or a shifted lognormal (right-skewed)."""
    z = rng.standard_normal((*size, len(loc)))
    if kind == "normal":
        return loc + scale * z
    s = LOGNORMAL_SIGMA
    return loc + scale * (np.exp(s * z) - np.exp(s * s / 2)) / np.sqrt((np.exp(s * s) - 1) * np.exp(s * s))


def _population_iqm(kind: str, loc: np.ndarray, scale: np.ndarray) -> float:
    """The IQM of the envs' pooled score distribution (equal weights), from 400,000 draws per env."""
    return interquartile_mean(_runs(np.random.default_rng(123), kind, loc, scale, (400_000,)))


def _plain_percentile(rng: np.random.Generator, runs: np.ndarray, n_boot: int) -> dict[str, np.ndarray]:
    """What the tables gave before: percentile intervals of the stratified bootstrap, for (trials, runs, envs)."""
    trials, n, envs = runs.shape
    rows = rng.integers(0, n, size=(trials, n_boot, n, envs))
    draws = np.sort(np.take_along_axis(runs[:, None], rows, axis=2).reshape(trials, n_boot, -1), axis=-1)
    cut = n * envs // 4
    iqm, mean = draws[..., cut:n * envs - cut].mean(-1), draws.mean(-1)
    return {"iqm": np.percentile(iqm, [2.5, 97.5], axis=1), "mean": np.percentile(mean, [2.5, 97.5], axis=1)}


def _coverage(low: np.ndarray, high: np.ndarray, truth: float) -> float:
    return float(np.mean((np.asarray(low) <= truth) & (truth <= np.asarray(high))))


#: Envs of AUROC-like scores (well apart, the IQM's hardest case here) and of rewards over a baseline's (ratio to
#: the baseline, its std) with the baseline's mean reward and coefficient of variation, as MuJoCo's runs have them.
AUROC_LOC, AUROC_SCALE = np.array([0.9, 0.85, 0.6, 0.55]), np.array([0.03, 0.05, 0.04, 0.08])
RATIO_LOC, RATIO_SCALE = np.array([0.8, 0.7, 1.5, 0.8]), np.array([0.12, 0.28, 0.7, 0.3])
BASELINE_LOC, BASELINE_CV = np.array([4500.0, 4450.0, 140.0, 2800.0]), np.array([0.15, 0.04, 0.03, 0.18])


def test_aggregate_intervals_cover_about_95_percent_at_our_sizes():
    """4 envs x 3 and x 5 seeds, normal and skewed runs, 600 simulated tables each: the floored intervals cover the
    population mean and IQM about 96% on average and >= 92% in every cell (the hardest, the skewed AUROC-like IQM,
    is about 93.7% over 6,000 tables), where the plain stratified percentile intervals covered 76-91%; and rewards
    over a baseline, re-normalized in every resample, where a normalizer held fixed covered 78-88%."""
    trials, n_boot, results = 600, 400, {}
    for kind in ("normal", "lognormal"):
        truth_iqm = _population_iqm(kind, AUROC_LOC, AUROC_SCALE)
        ratio_iqm = _population_iqm(kind, RATIO_LOC, RATIO_SCALE)
        for seeds in (3, 5):
            rng = np.random.default_rng([seeds, len(kind)])
            runs = _runs(rng, kind, AUROC_LOC, AUROC_SCALE, (trials, seeds))
            table = aggregate_table(dict(enumerate(runs)), n_boot=n_boot)
            old = _plain_percentile(rng, runs, n_boot)
            results["raw", kind, seeds] = (
                (_coverage(table["mean_low"], table["mean_high"], AUROC_LOC.mean()),
                 _coverage(*old["mean"], AUROC_LOC.mean())),
                (_coverage(table["iqm_low"], table["iqm_high"], truth_iqm), _coverage(*old["iqm"], truth_iqm)))
            x = _runs(rng, kind, RATIO_LOC * BASELINE_LOC, RATIO_SCALE * BASELINE_LOC, (trials, seeds))
            y = _runs(rng, kind, BASELINE_LOC, BASELINE_CV * BASELINE_LOC, (trials, seeds))
            table = pd.DataFrame([normalized_aggregate_table({"m": a, "baseline": b}, "baseline", n_boot).iloc[0]
                                  for a, b in zip(x, y)])
            old = _plain_percentile(rng, x / y.mean(axis=1, keepdims=True), n_boot)  # the normalizer held fixed
            results["normalized", kind, seeds] = (
                (_coverage(table["mean_low"], table["mean_high"], RATIO_LOC.mean()),
                 _coverage(*old["mean"], RATIO_LOC.mean())),
                (_coverage(table["iqm_low"], table["iqm_high"], ratio_iqm), _coverage(*old["iqm"], ratio_iqm)))
    print({cell: [f"{name} new {new:.3f} old {old:.3f}" for (new, old), name in zip(aggregates, ("mean", "iqm"))]
           for cell, aggregates in results.items()})
    pairs = [(cell, name, new, old) for cell, aggregates in results.items()
             for (new, old), name in zip(aggregates, ("mean", "iqm"))]
    for cell, name, new, old in pairs:
        assert 0.92 <= new <= 0.995 and old < new - 0.03, (cell, name, new, old)
    assert np.mean([new for *_, new, _ in pairs]) >= 0.945 and np.mean([old for *_, old in pairs]) < 0.87


# ------------------------------------------------------------------------------- floors, normalization, bad input
def test_the_mean_interval_is_never_narrower_than_stratified_t_and_the_iqm_widens_with_it():
    rng = np.random.default_rng(4)
    matrices = {f"m{i}": rng.normal(rng.uniform(0.5, 0.9, 4), 0.05, (3, 4)) for i in range(20)}
    table = aggregate_table(matrices, n_boot=300, seed=2).set_index("method")
    for method, matrix in matrices.items():
        row, (t_low, t_high) = table.loc[method], stratified_t_interval(matrix)
        assert row["mean_low"] <= t_low and row["mean_high"] >= t_high
        (draws,) = stratified_resamples([matrix], cell_rng(2, "aggregate", method), 300)
        plain = percentile_band(np.array([interquartile_mean(d) for d in draws]), 0.95)
        assert row["iqm_low"] <= min(plain[0], row["iqm"]) + 1e-12
        assert row["iqm_high"] >= max(plain[1], row["iqm"]) - 1e-12
    one_seed = aggregate_table({"m": matrices["m0"][:1]}, n_boot=50).iloc[0]
    assert np.isnan(one_seed[["iqm_low", "iqm_high", "mean_low", "mean_high"]].astype(float)).all()
    assert one_seed["iqm"] == pytest.approx(interquartile_mean(matrices["m0"][:1]))


def test_normalized_table_redraws_the_reference_and_marks_it_as_the_normalizer():
    x = np.array([[900.0, 50.0], [1100.0, 70.0], [1000.0, 60.0]])
    steady = np.array([[1000.0, 100.0], [1000.0, 100.0], [1000.0, 100.0]])
    noisy = np.array([[600.0, 80.0], [1400.0, 120.0], [1000.0, 100.0]])  # the same env means, 1000 and 100
    tables = {name: normalized_aggregate_table({"baseline": ref, "m": x}, "baseline", n_boot=500, seed=1)
              for name, ref in (("steady", steady), ("noisy", noisy))}
    for table in tables.values():
        assert list(table.columns) == NORMALIZED_COLUMNS and table["role"].tolist() == ["reference", "compared"]
        reference, compared = table.iloc[0], table.iloc[1]
        assert reference["mean"] == pytest.approx(1.0) and reference[["iqm_low", "mean_high"]].isna().all()
        assert compared["mean"] == pytest.approx((1.0 + 0.6) / 2) and compared[["iqm_low", "mean_high"]].notna().all()
    steady_row, noisy_row = tables["steady"].iloc[1], tables["noisy"].iloc[1]
    assert steady_row["mean"] == noisy_row["mean"] and steady_row["iqm"] == noisy_row["iqm"]  # same points
    assert noisy_row["mean_low"] < steady_row["mean_low"] and noisy_row["mean_high"] > steady_row["mean_high"]
    assert noisy_row["iqm_high"] - noisy_row["iqm_low"] > steady_row["iqm_high"] - steady_row["iqm_low"]
    t_steady = stratified_t_interval(x / steady.mean(axis=0))  # a reference without spread: the plain t floor
    assert ratio_t_interval(x, steady) == pytest.approx(t_steady)
    assert steady_row["mean_low"] <= t_steady[0] and steady_row["mean_high"] >= t_steady[1]
    again = normalized_aggregate_table({"baseline": noisy, "m": x}, "baseline", n_boot=500, seed=1)
    assert again.equals(tables["noisy"])  # seeded per cell


def test_bad_input_ends_in_one_clear_error():
    good = np.array([[1.0, 2.0], [1.5, 2.5], [2.0, 3.0]])
    with pytest.raises(ValueError, match="non-finite"):
        aggregate_table({"m": np.array([[1.0, np.nan], [1.0, 2.0]])}, n_boot=10)
    with pytest.raises(ValueError, match=r"\(runs, envs\) matrix"):
        aggregate_table({"m": np.arange(3.0)}, n_boot=10)
    with pytest.raises(ValueError, match="reference's \\(runs, envs\\) shape"):
        normalized_aggregate_table({"baseline": good, "m": good[:2]}, "baseline", n_boot=10)
    with pytest.raises(ValueError, match="must be one of the methods"):
        normalized_aggregate_table({"m": good}, "baseline", n_boot=10)
    with pytest.raises(ValueError, match="env column 1 must all be nonzero and of one sign"):
        normalized_aggregate_table({"baseline": np.array([[1.0, -1.0], [1.0, 1.0]]), "m": good[:2]}, "baseline", 10)
    with pytest.raises(ValueError, match="env column 0 must all be nonzero"):
        normalized_aggregate_table({"baseline": np.array([[0.0, 1.0], [0.0, 1.0]]), "m": good[:2]}, "baseline", 10)
    with pytest.raises(ValueError, match="non-finite"):
        normalized_aggregate_table({"baseline": good, "m": np.where(good > 2.9, np.inf, good)}, "baseline", 10)


def _reward_runs() -> pd.DataFrame:
    """Runs of two MuJoCo envs (3 seeds) and an Atari one (1 seed), as `normalized_rewards` gives them."""
    rng = np.random.default_rng(0)
    rows = [{"env": env, "method": method, "seed": seed, "reward": scale * factor * rng.uniform(0.8, 1.2)}
            for env, scale, seeds in (("HalfCheetah-v5", 4000.0, 3), ("Swimmer-v5", 100.0, 3),
                                      ("MsPacmanNoFrameskip-v4", 700.0, 1))
            for method, factor in (("baseline", 1.0), ("masksembles", 0.9), ("mc_dropout", 0.5))
            for seed in range(seeds)]
    runs = pd.DataFrame(rows)
    baseline = runs[runs["method"] == "baseline"].groupby("env")["reward"].mean()
    return runs.assign(normalized_reward=runs["reward"] / runs["env"].map(baseline))


def test_by_env_family_renormalizes_raw_rewards_by_the_baseline():
    runs, methods = _reward_runs(), ["baseline", "masksembles", "mc_dropout"]
    aggregates, improvements = by_env_family(runs, "reward", methods, n_boot=200, normalize_by="baseline")
    assert list(aggregates.columns) == ["family", *NORMALIZED_COLUMNS, "envs"]
    mujoco = aggregates[aggregates["family"] == "MuJoCo"].set_index("method")
    assert mujoco.loc["baseline", "role"] == "reference" and np.isnan(mujoco.loc["baseline", "mean_low"])
    assert mujoco.loc["baseline", "mean"] == pytest.approx(1.0) and mujoco.loc["mc_dropout", "role"] == "compared"
    assert (aggregates[aggregates["family"] == "Atari"]["mean_low"].isna()).all()  # one seed per env: no interval
    old_aggregates, old_improvements = by_env_family(runs, "normalized_reward", methods, n_boot=200)  # old call
    assert "role" not in old_aggregates.columns and len(old_aggregates) == len(aggregates)
    assert np.allclose(old_aggregates[["iqm", "mean"]], aggregates[["iqm", "mean"]])  # the same points
    assert improvements.equals(old_improvements)  # one env's positive scale changes no comparison
    shown = by_env_family(runs, "reward", methods[1:], n_boot=50, normalize_by="baseline")[0]
    assert "baseline" not in set(shown["method"]) and set(shown["role"]) == {"compared"}  # normalizer, not shown
    assert by_env_family(runs[runs["method"] != "baseline"], "reward", methods, 50, normalize_by="baseline")[0].empty
