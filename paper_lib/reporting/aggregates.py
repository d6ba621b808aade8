"""Across envs, as rliable aggregates (Agarwal et al. 2021, "Deep RL at the Edge of the Statistical Precipice"):
interquartile mean (IQM) and mean over all runs of all envs, with stratified-bootstrap intervals, the
probability that one method improves on another, and performance profiles (the fraction of runs above each score).

A method's scores form a (runs, envs) matrix: one column per env, one row per seed. The stratified bootstrap
resamples the runs of each env apart (with replacement), so every env keeps its weight (the draws and the
percentile intervals live in `scoring.statistics`; here the aggregates and their tables). rliable itself does not
run here: its newest release (1.2.0) needs arch < 8, whose 7.x fails to import under the lock's pandas 3 and whose
8.0 changed the bootstrap API rliable calls; these are its definitions, written out and tested against hand-made
cases (tests/reporting/test_aggregates.py).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.stats import trim_mean

from paper_lib.scoring.statistics import cell_rng, percentile_band, stratified_interval, stratified_replicates

#: The paper's pairwise claims about its methods: (better, worse) as the paper reads them.
PAPER_PAIRS = (("masksembles", "mc_dropout"), ("masksembles", "mc_dropconnect"), ("masksembles", "ensemble"),
               ("ensemble", "mc_dropout"), ("ensemble", "mc_dropconnect"))
AGGREGATE_COLUMNS = ["method", "iqm", "iqm_low", "iqm_high", "mean", "mean_low", "mean_high", "n_envs",
                     "seeds_per_env"]
IMPROVEMENT_COLUMNS = ["method", "over", "probability", "ci_low", "ci_high", "n_envs", "seeds_per_env"]


def complete_envs(scores: pd.DataFrame, methods: list[str]) -> list[str]:
    """The envs where every method has runs of the same seeds, with the most common seed count among them.

    A stratified bootstrap needs the same runs per env for every method it compares, so an env where some method
    lacks a seed the others have is left out.
    """
    seeds = scores.groupby(["env", "method"], sort=False)["seed"].apply(frozenset).unstack("method")
    complete = [env for env, row in seeds.iterrows()
                if all(isinstance(row.get(m), frozenset) for m in methods) and len({row[m] for m in methods}) == 1]
    counts = [len(seeds.loc[env, methods[0]]) for env in complete]
    return [env for env, n in zip(complete, counts) if n == max(set(counts), key=counts.count)] if complete else []


def score_matrices(scores: pd.DataFrame, value: str, methods: list[str]) -> dict[str, np.ndarray]:
    """{method: (seeds, envs) matrix of `value`} over `complete_envs`; `scores` has one row per run (env, method,
    seed, value)."""
    envs = complete_envs(scores, methods)
    runs = scores.sort_values("seed")
    return {method: np.column_stack([runs[(runs["env"] == env) & (runs["method"] == method)][value].to_numpy(float)
                                     for env in envs]) for method in methods} if envs else {}


def interquartile_mean(matrix: np.ndarray) -> float:
    """The mean of the middle 50% of all runs' scores: robust to a few outlying runs, less noisy than the median."""
    return float(trim_mean(np.asarray(matrix, dtype=float).ravel(), proportiontocut=0.25))


def _iqm_and_mean(matrix: np.ndarray) -> tuple[float, float]:
    """Both aggregates of one resample, so that their intervals come from the same draws."""
    return interquartile_mean(matrix), matrix.mean()


def aggregate_table(matrices: dict[str, np.ndarray], n_boot: int, seed: int = 0, level: float = 0.95) -> pd.DataFrame:
    """IQM and mean of each method's scores, with percentile intervals of a stratified bootstrap over runs."""
    rows = []
    for method, matrix in matrices.items():
        boot = stratified_replicates(_iqm_and_mean, [matrix], cell_rng(seed, "aggregate", method), n_boot)
        runs = matrix.shape[0]
        rows.append({"method": method, "iqm": interquartile_mean(matrix), **dict(zip(("iqm_low", "iqm_high"),
                     stratified_interval(boot[:, 0], level, runs))), "mean": float(matrix.mean()),
                     **dict(zip(("mean_low", "mean_high"), stratified_interval(boot[:, 1], level, runs))),
                     "n_envs": matrix.shape[1], "seeds_per_env": matrix.shape[0]})
    return pd.DataFrame(rows, columns=AGGREGATE_COLUMNS)


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y): per env, the share of (run of X, run of Y) pairs where X scores higher (ties count half), averaged
    over envs (rliable's definition, the Mann-Whitney U statistic per env)."""
    per_env = []
    for column in range(x.shape[1]):
        a, b = x[:, column][:, None], y[:, column][None, :]
        per_env.append(float(np.mean((a > b) + 0.5 * (a == b))))
    return float(np.mean(per_env))


def improvement_table(matrices: dict[str, np.ndarray], pairs: tuple[tuple[str, str], ...] = PAPER_PAIRS,
                      n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> pd.DataFrame:
    """P(method improves on `over`) for each pair whose methods both have scores, with a stratified-bootstrap
    interval (the runs of each method resampled apart, env by env)."""
    rows = []
    for method, over in pairs:
        if method not in matrices or over not in matrices:
            continue
        x, y = matrices[method], matrices[over]
        boot = stratified_replicates(probability_of_improvement, [x, y], cell_rng(seed, "improvement", method, over),
                                     n_boot)
        rows.append({"method": method, "over": over, "probability": probability_of_improvement(x, y),
                     **dict(zip(("ci_low", "ci_high"), stratified_interval(boot, level, x.shape[0]))),
                     "n_envs": x.shape[1], "seeds_per_env": x.shape[0]})
    return pd.DataFrame(rows, columns=IMPROVEMENT_COLUMNS)


def normalized_rewards(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per run: its mean sampled reward (combined inference for member methods, as the paper's Table 1)
    divided by the mean of the baseline's runs in the same env, so envs of different reward scales can pool."""
    sampled = episodes[~episodes["deterministic"].astype(bool)]
    sampled = sampled[(sampled["method"] == "baseline") | (sampled["inference"] == "combined")]
    runs = sampled.groupby(["env", "method", "seed"], as_index=False)["reward"].mean()
    baseline = runs[runs["method"] == "baseline"].groupby("env")["reward"].mean()
    runs = runs[runs["env"].isin(baseline.index)]
    return runs.assign(normalized_reward=runs["reward"] / runs["env"].map(baseline))


def by_env_family(scores: pd.DataFrame, value: str, methods: list[str], n_boot: int,
                  seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(aggregates, probabilities of improvement) of `value`, MuJoCo and Atari apart (their seed counts and
    scales differ), each with a `family` column and the envs it pooled."""
    from paper_lib.agents.envs import is_atari

    aggregates, improvements = [], []
    for family, part in scores.groupby(scores["env"].map(lambda e: "Atari" if is_atari(e) else "MuJoCo"), sort=False):
        present = [m for m in methods if m in set(part["method"])]
        matrices = score_matrices(part, value, present)
        if not matrices:
            continue
        envs = ", ".join(complete_envs(part, present))
        aggregates.append(aggregate_table(matrices, n_boot, seed).assign(family=family, envs=envs))
        improvements.append(improvement_table(matrices, n_boot=n_boot, seed=seed).assign(family=family))
    columns = ["family", *AGGREGATE_COLUMNS, "envs"], ["family", *IMPROVEMENT_COLUMNS]
    return tuple(pd.concat(parts, ignore_index=True)[cols] if parts else pd.DataFrame(columns=cols)
                 for parts, cols in zip((aggregates, improvements), columns))


# ------------------------------------------------------------------------------------- performance profiles

#: The columns of `performance_profile` and `profiles_by_env_family` (the latter adds family and envs).
PROFILE_COLUMNS = ["method", "tau", "fraction", "fraction_low", "fraction_high", "n_envs", "seeds_per_env"]


def score_distribution(matrix: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Per tau, the fraction of all runs of all envs whose score exceeds tau (rliable's run-score distribution).

    Pooling the runs weighs every env equally because every env has the same number of runs
    (`score_matrices`); a whole curve shows what one number (IQM, mean) hides: how the runs spread.
    """
    scores = np.asarray(matrix, dtype=float).ravel()
    return (scores[None, :] > np.asarray(taus, dtype=float)[:, None]).mean(axis=1)


def profile_taus(matrices: dict[str, np.ndarray], n: int = 101) -> np.ndarray:
    """`n` thresholds from just below the lowest to the highest score of any method (a 2% margin of their range
    below), so every method's curve runs from 1 down to 0."""
    scores = np.concatenate([np.asarray(m, dtype=float).ravel() for m in matrices.values()])
    low, high = float(scores.min()), float(scores.max())
    return np.linspace(low - 0.02 * (high - low or 1.0), high, n)


def performance_profile(matrices: dict[str, np.ndarray], taus: np.ndarray, n_boot: int, seed: int = 0,
                        level: float = 0.95) -> pd.DataFrame:
    """Each method's score distribution at every tau, with a pointwise stratified-bootstrap percentile band.

    One seed per env has no band (NaN), as the aggregate tables have no interval there: resampling
    one run per env only repeats it.
    """
    taus = np.asarray(taus, dtype=float)
    parts = []
    for method, matrix in matrices.items():
        if matrix.shape[0] < 2:  # as `stratified_interval`: one run per env has no interval
            low = high = np.full(taus.shape, np.nan)
        else:
            boot = stratified_replicates(lambda m: score_distribution(m, taus), [matrix],
                                         cell_rng(seed, "profile", method), n_boot)
            low, high = percentile_band(boot, level, axis=0)
        parts.append(pd.DataFrame({"method": method, "tau": taus, "fraction": score_distribution(matrix, taus),
                                   "fraction_low": low, "fraction_high": high, "n_envs": matrix.shape[1],
                                   "seeds_per_env": matrix.shape[0]}))
    return pd.concat(parts, ignore_index=True)[PROFILE_COLUMNS] if parts else pd.DataFrame(columns=PROFILE_COLUMNS)


def profiles_by_env_family(scores: pd.DataFrame, value: str, methods: list[str], n_boot: int, seed: int = 0,
                           taus: np.ndarray | None = None) -> pd.DataFrame:
    """`performance_profile` of `value`, MuJoCo and Atari apart (as `by_env_family`), with family and envs columns;
    `taus` default to each family's own score range (`profile_taus`)."""
    from paper_lib.agents.envs import is_atari

    parts = []
    for family, part in scores.groupby(scores["env"].map(lambda e: "Atari" if is_atari(e) else "MuJoCo"), sort=False):
        present = [m for m in methods if m in set(part["method"])]
        matrices = score_matrices(part, value, present)
        if not matrices:
            continue
        grid = profile_taus(matrices) if taus is None else taus
        parts.append(performance_profile(matrices, grid, n_boot, seed).assign(
            family=family, envs=", ".join(complete_envs(part, present))))
    columns = ["family", *PROFILE_COLUMNS, "envs"]
    return pd.concat(parts, ignore_index=True)[columns] if parts else pd.DataFrame(columns=columns)
