"""The statistics every table interval rests on (paper_lib/scoring/statistics.py): the bootstraps' draws, intervals
over seeds (never narrower than Student's t, issue 36) and of differences, and the helpers the tables call."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.stats import t as student_t

from paper_lib.scoring.statistics import (bootstrap_t_interval, cell_rng, cluster_resamples, difference_ci,
                                          mean_replicates, percentile_band, ratio_mean_variance, ratio_t_interval,
                                          resample_counts, satterthwaite_interval, seed_cluster_ci,
                                          seed_cluster_difference, seed_cluster_replicates, seed_mean_ci,
                                          seed_mean_difference_ci, seed_mean_std, stratified_interval,
                                          stratified_mean_variance, stratified_replicates, stratified_resample,
                                          stratified_resamples, stratified_t_interval, t_interval, welch_interval)


# ------------------------------------------------------------------------------------------------- seeds, then clusters
def test_seed_cluster_ci_resamples_seeds_then_clusters():
    rng = np.random.default_rng(0)
    reps = [rng.normal(mean, 0.01, 1000) for mean in (0.6, 0.7, 0.8)]
    boot = seed_cluster_replicates(reps, np.random.default_rng(1), n_boot=2000)
    # seeds are resampled: draws of (0.6, 0.6, 0.6) or (0.8, 0.8, 0.8) happen (1 in 27 each), so the replicates
    # reach the seed means; without seed resampling every replicate would be 0.7 +- 0.01
    assert np.quantile(boot, 0.02) < 0.64 and np.quantile(boot, 0.98) > 0.76
    low, high = seed_cluster_ci(reps, np.random.default_rng(1), n_boot=2000)
    assert (low, high) == pytest.approx(t_interval([0.6, 0.7, 0.8]), abs=2e-3)  # 3 seeds: never narrower than t
    assert seed_cluster_ci(reps[:1], rng) == tuple(np.quantile(reps[0], [0.025, 0.975]))
    with pytest.raises(ValueError, match="one per training seed"):
        seed_cluster_ci([], rng)


def test_difference_ci_pairings():
    rng = np.random.default_rng(0)
    reps = [rng.normal(0.7 + 0.05 * s, 0.05, 400) for s in range(3)]
    assert difference_ci(reps, reps, np.random.default_rng(1), "paired") == (0.0, 0.0)
    for pairing in ("seeds", "unpaired"):
        low, high = difference_ci(reps, reps, np.random.default_rng(1), pairing)
        assert low < 0 < high, pairing
    one = reps[:1]
    assert difference_ci(one, one, np.random.default_rng(1), "paired") == (0.0, 0.0)
    assert np.ptp(seed_cluster_difference(one, one, np.random.default_rng(1), "unpaired")) > 0  # matched at random
    with pytest.raises(ValueError, match="pairing must be one of"):
        difference_ci(reps, reps, rng, "both")
    with pytest.raises(ValueError, match="same seeds"):
        difference_ci(reps, reps[:2], rng, "paired")


def test_seed_cluster_ci_draws_seeds_then_replicates_and_floors_at_t():
    """The bootstrap part draws exactly as before (seeds, then one replicate per drawn seed: single-run scores depend
    on it); the interval reported over 3 seeds is that percentile interval widened to Student's t."""
    rng = np.random.default_rng(0)
    reps = [rng.normal(m, 0.02, 300) for m in (0.6, 0.7, 0.8)]
    draw = np.random.default_rng(9)
    seeds = draw.integers(0, 3, size=(500, 3))
    picks = draw.random(size=(500, 3))
    stacked = np.stack(reps)
    expected = np.nanquantile(stacked[seeds, (picks * 300).astype(int)].mean(axis=1), [0.025, 0.975])
    assert np.quantile(seed_cluster_replicates(reps, np.random.default_rng(9), 500), [0.025, 0.975]) == pytest.approx(expected)
    floor = t_interval([r.mean() for r in reps])
    assert seed_cluster_ci(reps, np.random.default_rng(9), n_boot=500) == (min(expected[0], floor[0]),
                                                                         max(expected[1], floor[1]))
    assert seed_cluster_ci(reps[:1], np.random.default_rng(9), n_boot=500) == tuple(np.quantile(reps[0], [0.025, 0.975]))


# ------------------------------------------------------------------------------------------------- coverage (issue 36)
def test_intervals_over_three_seeds_cover_about_95_percent():
    """Synthetic runs: 3 seeds whose means vary, 10 episodes each. The reported interval covers the true mean
    about 95% of the time; the hierarchical percentile bootstrap alone (what the tables used) far less."""
    rng = np.random.default_rng(0)
    trials, covered, covered_percentile = 400, 0, 0
    for _ in range(trials):
        episodes = [rng.normal(mean, 0.5, 10) for mean in rng.normal(0.0, 1.0, 3)]
        reps = [mean_replicates(e, rng, 200) for e in episodes]
        low, high = seed_cluster_ci(reps, rng, 200, estimates=[e.mean() for e in episodes])
        covered += low <= 0.0 <= high
        p_low, p_high = np.quantile(seed_cluster_replicates(reps, rng, 200), [0.025, 0.975])
        covered_percentile += p_low <= 0.0 <= p_high
    assert 0.93 <= covered / trials <= 0.995
    assert covered_percentile / trials < 0.85


def test_seed_interval_is_never_narrower_than_t_and_keeps_the_within_seed_part():
    rng = np.random.default_rng(0)
    between = [rng.normal(mean, 0.01, 1000) for mean in (0.6, 0.7, 0.8)]  # seeds differ, runs are precise
    assert seed_cluster_ci(between, np.random.default_rng(1), 2000) == pytest.approx(t_interval([0.6, 0.7, 0.8]), abs=2e-3)
    within = [rng.normal(0.7, 0.1, 1000) for _ in range(3)]  # seeds agree, each run is noisy
    low, high = seed_cluster_ci(within, np.random.default_rng(1), 2000)
    t_low, t_high = t_interval([r.mean() for r in within])
    assert low < t_low and high > t_high  # the hierarchical bootstrap's within-seed part is wider here
    assert low == pytest.approx(np.quantile(seed_cluster_replicates(within, np.random.default_rng(1), 2000), 0.025))


def test_difference_intervals_are_at_least_t_over_the_seed_differences():
    a = [np.full(50, v) for v in (1.0, 2.0, 3.0)]
    b = [np.full(50, v) for v in (0.0, 0.5, 2.5)]
    paired = difference_ci(a, b, np.random.default_rng(0), "paired", estimates_a=[1, 2, 3], estimates_b=[0, 0.5, 2.5])
    assert paired == pytest.approx(t_interval([1.0, 1.5, 0.5]))
    unpaired = difference_ci(a, b, np.random.default_rng(0), "unpaired")
    assert unpaired == pytest.approx(welch_interval([1, 2, 3], [0, 0.5, 2.5]))
    one = difference_ci(a[:1], b[:1], np.random.default_rng(0), "paired")  # one seed: that run's own interval
    assert one == (1.0, 1.0)


# ------------------------------------------------------------------------------------------------- means of episodes
def test_one_seed_resamples_its_episodes_only():
    values = np.arange(10.0)
    low, high = seed_cluster_ci([mean_replicates(values, np.random.default_rng(3), 400)], np.random.default_rng(4))
    reps = mean_replicates(values, np.random.default_rng(3), 400)
    assert (low, high) == pytest.approx(np.quantile(reps, [0.025, 0.975]))
    assert mean_replicates(np.full(7, 2.5), np.random.default_rng(0), 50) == pytest.approx(np.full(50, 2.5))


def test_mean_replicates_draw_counts_of_episodes_with_replacement():
    values = np.arange(12.0)
    counts = resample_counts(12, 300, np.random.default_rng(4))
    assert counts.shape == (300, 12) and (counts.sum(axis=1) == 12).all()
    assert np.array_equal(mean_replicates(values, np.random.default_rng(4), 300), values @ counts.T / 12)
    both = mean_replicates(np.stack([values, 2 * values]), np.random.default_rng(4), 300)  # rows share the draws
    assert np.array_equal(both[1], 2 * both[0])


def test_seed_mean_ci_is_the_seed_cluster_ci_of_each_seeds_episode_replicates():
    rng = np.random.default_rng(0)
    episodes = [rng.normal(m, 5, 10) for m in (95.0, 100.0, 108.0)]
    draw = np.random.default_rng(7)
    per_seed = [mean_replicates(e, draw, 400) for e in episodes]
    expected = seed_cluster_ci(per_seed, draw, 400, estimates=[e.mean() for e in episodes])
    assert seed_mean_ci(episodes, np.random.default_rng(7), 400) == expected
    low, high = seed_mean_ci(episodes[:1], np.random.default_rng(7), 400)  # one seed: its episodes only
    assert (low, high) == tuple(np.quantile(mean_replicates(episodes[0], np.random.default_rng(7), 400), [0.025, 0.975]))


def test_seed_mean_difference_ci_pairs_episodes_with_the_same_draws():
    rng = np.random.default_rng(1)
    a = [rng.normal(0, 50, 8) for _ in range(3)]
    assert seed_mean_difference_ci(a, a, np.random.default_rng(2), "paired", 300) == (0.0, 0.0)
    low, high = seed_mean_difference_ci(a, a, np.random.default_rng(2), "unpaired", 300)
    assert low < 0 < high
    draw = np.random.default_rng(3)
    reps_a, reps_b = [mean_replicates(x, draw, 300) for x in a], [mean_replicates(x, draw, 300) for x in a[:2]]
    expected = difference_ci(reps_a, reps_b, draw, "unpaired", 300, estimates_a=[x.mean() for x in a],
                             estimates_b=[x.mean() for x in a[:2]])
    assert seed_mean_difference_ci(a, a[:2], np.random.default_rng(3), "unpaired", 300) == expected
    with pytest.raises(ValueError, match="same seeds and the same number of episodes"):
        seed_mean_difference_ci(a, [x[:5] for x in a], np.random.default_rng(0), "paired", 10)


def test_seed_mean_std_is_the_spread_of_seed_means_beside_that_of_all_rows():
    df = pd.DataFrame({"cell": ["x"] * 6 + ["y"] * 2, "seed": [0, 0, 1, 1, 2, 2, 0, 0],
                       "v": [1.0, 3.0, 4.0, 6.0, 7.0, 9.0, 1.0, 2.0]})
    out = seed_mean_std(df, ["cell"], "v").set_index("cell")
    assert list(out.columns) == ["mean", "std", "n_seeds", "row_std", "n_rows"]
    assert out.loc["x", "mean"] == pytest.approx(5.0) and out.loc["x", "std"] == pytest.approx(3.0)  # means 2, 5, 8
    assert out.loc["x", "n_seeds"] == 3 and out.loc["x", "n_rows"] == 6
    assert out.loc["x", "row_std"] == pytest.approx(np.std([1, 3, 4, 6, 7, 9], ddof=1))
    assert np.isnan(out.loc["y", "std"]) and out.loc["y", "row_std"] == pytest.approx(np.std([1, 2], ddof=1))


# ------------------------------------------------------------------------------------------------- clusters
def test_a_shared_cluster_moves_both_sides_and_own_clusters_are_drawn_apart():
    id_labels = np.array(["e0", "e0", "e1", "e2"])
    ood_labels = np.array(["e1", "c0", "c0", "c1", "e0"])  # e1, e0: made from those ID episodes; c0, c1: their own
    chunks = list(cluster_resamples(id_labels, ood_labels, np.random.default_rng(0), n_boot=25, chunk=10))
    assert [w.shape[0] for w, _ in chunks] == [10, 10, 5]
    for w_id, w_ood in chunks:
        assert (w_id[:, 0] == w_id[:, 1]).all()  # one episode, one draw
        assert (w_ood[:, 0] == w_id[:, 2]).all() and (w_ood[:, 4] == w_id[:, 0]).all()
        assert (w_ood[:, 1] == w_ood[:, 2]).all() and (w_ood[:, 1] + w_ood[:, 3] == 2).all()  # 2 own clusters
        assert (w_id[:, [0, 2, 3]].sum(axis=1) == 3).all()  # 3 ID clusters drawn 3 times


# ------------------------------------------------------------------------------------------------- stratified, seeding
def test_stratified_replicates_resample_each_matrix_in_turn():
    x, y = np.arange(6.0).reshape(3, 2), 10 + np.arange(6.0).reshape(3, 2)
    draw = np.random.default_rng(5)
    expected = [(stratified_resample(x, draw).sum(), stratified_resample(y, draw).sum()) for _ in range(20)]
    got = stratified_replicates(lambda a, b: (a.sum(), b.sum()), [x, y], np.random.default_rng(5), 20)
    assert np.array_equal(got, np.array(expected))


def test_stratified_interval_needs_two_runs_per_env():
    values = np.linspace(0.0, 1.0, 101)
    assert np.isnan(stratified_interval(values, 0.9, runs_per_env=1)).all()  # one run per env: no interval
    assert stratified_interval(values, 0.9, 2) == pytest.approx((0.05, 0.95))
    band = percentile_band(np.stack([values, 2 * values], axis=1), 0.9, axis=0)
    assert band.shape == (2, 2) and band[:, 1] == pytest.approx(2 * band[:, 0])


def test_cell_rng_depends_on_the_seed_and_the_key_only():
    assert np.array_equal(cell_rng(0, "E", "m", True).random(3), cell_rng(0, "E", "m", True).random(3))
    assert not np.array_equal(cell_rng(0, "E", "m").random(3), cell_rng(1, "E", "m").random(3))
    assert not np.array_equal(cell_rng(0, "E", "m").random(3), cell_rng(0, "E", "n").random(3))


# ------------------------------------------------------------------------------------------------- floors across envs
def test_stratified_resamples_draw_each_env_apart_all_at_once():
    x, y = np.arange(6.0).reshape(3, 2), 10 + np.arange(6.0).reshape(3, 2)
    a, b = stratified_resamples([x, y], np.random.default_rng(5), 200)
    assert a.shape == b.shape == (200, 3, 2)
    assert set(a[:, :, 0].ravel()) == {0.0, 2.0, 4.0} and set(b[:, :, 1].ravel()) == {11.0, 13.0, 15.0}
    again = stratified_resamples([x, y], np.random.default_rng(5), 200)
    assert np.array_equal(a, again[0]) and np.array_equal(b, again[1])
    assert np.array_equal(stratified_resamples([x], np.random.default_rng(5), 200)[0], a)  # each matrix in turn
    assert not np.array_equal(a - x.min(), b - y.min())  # drawn apart, not with the same rows
    with pytest.raises(ValueError, match="n_boot"):
        stratified_resamples([x], np.random.default_rng(0), 0)


def test_satterthwaite_interval_is_welch_for_two_samples_and_t_for_one():
    a, b = np.array([1.0, 2.0, 4.0]), np.array([0.0, 0.5, 2.5, 3.0])
    welch = satterthwaite_interval(a.mean() - b.mean(), [a.var(ddof=1) / 3, b.var(ddof=1) / 4], [2, 3])
    assert welch == pytest.approx(welch_interval(a, b))
    assert satterthwaite_interval(a.mean(), [a.var(ddof=1) / 3], [2]) == pytest.approx(t_interval(a))
    assert satterthwaite_interval(0.7, [0.0, 0.0], [2, 2]) == (0.7, 0.7)
    with pytest.raises(ValueError, match="one dof > 0 per component"):
        satterthwaite_interval(0.0, [1.0, np.nan], [2, 2])


def test_stratified_t_interval_pools_the_envs_variances_with_satterthwaite_df():
    matrix = np.array([[0.60, 0.90], [0.70, 0.80], [0.80, 0.85]])
    assert stratified_t_interval(matrix[:, :1]) == pytest.approx(t_interval(matrix[:, 0]))  # one env: t over its runs
    v = matrix.var(axis=0, ddof=1) / 3
    se, df = np.sqrt(v.sum()) / 2, v.sum() ** 2 / np.sum(v ** 2 / 2)
    half = student_t.ppf(0.975, df) * se
    assert stratified_t_interval(matrix) == pytest.approx((matrix.mean() - half, matrix.mean() + half))
    estimate, parts, dofs = stratified_mean_variance(np.stack([matrix, matrix[::-1]]))  # batched: per resample
    assert estimate == pytest.approx([matrix.mean()] * 2) and parts.shape == (2, 2) and dofs.tolist() == [2.0, 2.0]
    with pytest.raises(ValueError, match="two or more runs per env"):
        stratified_t_interval(matrix[:1])


def test_ratio_t_interval_adds_the_denominators_delta_method_variance():
    x = np.array([[90.0, 5.0], [110.0, 7.0], [100.0, 6.0]])
    steady = np.array([[100.0, 10.0]] * 3)
    assert ratio_t_interval(x, steady) == pytest.approx(stratified_t_interval(x / 10 ** np.array([2, 1])))
    noisy = np.array([[80.0, 9.0], [120.0, 11.0], [100.0, 10.0]])
    low, high = ratio_t_interval(x, noisy)
    s_low, s_high = ratio_t_interval(x, steady)
    assert low < s_low and high > s_high
    estimate, parts, dofs = ratio_mean_variance(x, noisy)
    ratio = x.mean(axis=0) / noisy.mean(axis=0)
    assert estimate == pytest.approx(ratio.mean()) and dofs.tolist() == [2.0, 2.0, 2.0, 2.0]
    assert parts[2] == pytest.approx(ratio[0] ** 2 * noisy[:, 0].var(ddof=1) / 3 / 100 ** 2 / 4)
    with pytest.raises(ValueError, match="nonzero denominator"):
        ratio_t_interval(x, np.array([[1.0, 1.0], [-1.0, 1.0], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="same envs"):
        ratio_t_interval(x, noisy[:, :1])


def test_bootstrap_t_interval_follows_the_skew_of_the_studentized_replicates():
    t_values = np.linspace(-2.0, 4.0, 1001)  # right-skewed studentized replicates, se 1 each
    low, high = bootstrap_t_interval(10.0, 0.5, 10.0 + t_values, np.ones_like(t_values), level=0.9)
    q_low, q_high = np.quantile(t_values, [0.05, 0.95])
    assert (low, high) == pytest.approx((10.0 - 0.5 * q_high, 10.0 - 0.5 * q_low))
    assert 10.0 - low > high - 10.0  # a long right tail of (replicate - estimate) moves the interval down
    with_zero = bootstrap_t_interval(10.0, 0.5, np.append(10.0 + t_values, 50.0), np.append(np.ones_like(t_values), 0),
                                     level=0.9)
    assert with_zero == (low, high)  # a replicate without spread is left out
    assert bootstrap_t_interval(3.0, 0.0, t_values, np.ones_like(t_values)) == (3.0, 3.0)
