"""Across envs, as rliable aggregates (Agarwal et al. 2021, "Deep RL at the Edge of the Statistical Precipice"):
interquartile mean (IQM) and mean over all runs of all envs, with stratified-bootstrap intervals, the
probability that one method improves on another, and performance profiles (the fraction of runs above each score).

A method's scores form a (runs, envs) matrix: one column per env, one row per seed. The stratified bootstrap
resamples the runs of each env apart (with replacement), so every env keeps its weight (the draws and the
intervals live in `scoring.statistics`; here the aggregates and their tables). rliable itself does not
run here: its newest release (1.2.0) needs arch < 8, whose 7.x fails to import under the lock's pandas 3 and whose
8.0 changed the bootstrap API rliable calls; these are its definitions, written out and tested against hand-made
cases (tests/reporting/test_aggregates.py).

Intervals of the IQM and the mean (`aggregate_table`). rliable's percentile intervals over 3 runs per env span about
each env's min-max and covered only 76-91% in simulation (4 envs x 3 and x 5 seeds), so, as every interval over few
seeds in this project, they have a floor. The mean's interval is the hull of its percentile band, Student's t over
the runs (the stratified t: se = sqrt(sum_e s_e^2 / n_e) / E, Welch-Satterthwaite df over the envs) and the
studentized (bootstrap-t) interval, which follows the runs' skew where t alone covered about 92% of skewed runs. The
IQM has no closed-form variance: its percentile band is widened about the IQM, each side, by the factor by which
the mean's band fell short of the mean's interval (>= 1), as both come from the same draws. The simulation in
tests/reporting/test_aggregates.py holds them at about 96% (>= 92% in every cell, normal and lognormal runs).
One run per env has no interval (NaN): resampling only repeats it.

Normalized scores (`normalized_aggregate_table`, `by_env_family(..., normalize_by="baseline")`). A reward over its
env's baseline mean pools envs of different scales, but that mean is itself an estimate from a few runs: each
replicate re-draws the baseline's runs of every env (apart from the method's, other training runs) and divides by
the replicate's own baseline mean. The mean's t floor is the delta-method variance of each env's ratio of means
(the method's and the baseline's run variances, 2E components, Satterthwaite df), its studentized bootstrap from the
same per-replicate variances. A normalizer held fixed covered 78-88%. The baseline's own row is 1.0 by
construction: role "reference", no interval. `normalized_rewards` still gives each run's normalized reward (for the
performance profiles); aggregating that column directly holds the normalizer fixed.

Descriptive only, without a floor: probabilities of improvement (`improvement_table`) carry stratified-bootstrap
percentile intervals, narrow at 3 runs per env as the aggregates' were, and no verdict reads them; performance
profile bands (`performance_profile`) are pointwise percentile bands of the same bootstrap.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.stats import trim_mean

from paper_lib.scoring.statistics import (bootstrap_t_interval, cell_rng, percentile_band, ratio_mean_variance,
                                          satterthwaite_interval, stratified_interval, stratified_mean_variance,
                                          stratified_replicates, stratified_resamples)

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


def _check_matrix(name: str, matrix: np.ndarray) -> np.ndarray:
    """A method's (runs, envs) scores as floats, or one ValueError naming what is wrong with them."""
    m = np.asarray(matrix, dtype=float)
    if m.ndim != 2 or m.size == 0:
        raise ValueError(f"scores of {name!r} must be a non-empty (runs, envs) matrix, got shape {m.shape}.")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"scores of {name!r} hold non-finite values (NaN or inf): an aggregate needs every run.")
    return m


def _iqm_of_resamples(resamples: np.ndarray) -> np.ndarray:
    """`interquartile_mean` of each (runs, envs) resample along the first axis (scipy's trim_mean: int(n/4) runs
    cut at each end of the sorted runs), vectorized so a coverage simulation stays fast."""
    flat = np.sort(resamples.reshape(resamples.shape[0], -1), axis=1)
    cut = int(0.25 * flat.shape[1])
    return flat[:, cut:flat.shape[1] - cut].mean(axis=1)


def _about(point: float, band: np.ndarray, factor: float) -> tuple[float, float]:
    """`band` (holding `point`) widened about `point`, each side by `factor`: the IQM's asymmetry is kept."""
    low, high = min(float(band[0]), point), max(float(band[1]), point)
    return point - factor * (point - low), point + factor * (high - point)


def _floored_intervals(iqm: float, boot_iqm: np.ndarray, boot_mean: np.ndarray, floors: list[tuple[float, float]],
                       level: float) -> dict[str, float]:
    """IQM and mean intervals from replicates of both (the same draws), never narrower than the mean's `floors`.

    The mean's is the hull of its percentile band and its floors (Student's t and the studentized bootstrap). The IQM
    has no closed-form floor; its band is widened about the IQM by the factor by which the mean's band fell short of
    the mean's interval (>= 1): both bands come from the same draws and miss the same small-sample spread.
    """
    iqm_band, mean_band = percentile_band(boot_iqm, level), percentile_band(boot_mean, level)
    mean_low = min(float(mean_band[0]), *(f[0] for f in floors))
    mean_high = max(float(mean_band[1]), *(f[1] for f in floors))
    band_width = float(mean_band[1] - mean_band[0])
    factor = max(1.0, (mean_high - mean_low) / band_width) if band_width > 0 else 1.0
    iqm_low, iqm_high = _about(iqm, iqm_band, factor)
    return {"iqm_low": iqm_low, "iqm_high": iqm_high, "mean_low": mean_low, "mean_high": mean_high}


def _mean_floors(point: tuple[np.ndarray, np.ndarray, np.ndarray], boot: tuple[np.ndarray, np.ndarray, np.ndarray],
                 level: float) -> list[tuple[float, float]]:
    """Student's t and the studentized bootstrap of a mean over envs, from the (estimate, variance components, dofs)
    of the data (`point`) and of every resample (`boot`, leading axis the replicates)."""
    estimate, variances, dofs = point
    return [satterthwaite_interval(float(estimate), variances, dofs, level),
            bootstrap_t_interval(float(estimate), float(np.sqrt(variances.sum())), boot[0],
                                 np.sqrt(boot[1].sum(axis=-1)), level)]


_NO_INTERVAL = {"iqm_low": np.nan, "iqm_high": np.nan, "mean_low": np.nan, "mean_high": np.nan}


def aggregate_table(matrices: dict[str, np.ndarray], n_boot: int, seed: int = 0, level: float = 0.95) -> pd.DataFrame:
    """IQM and mean of each method's scores, with stratified-bootstrap intervals floored at t (`_floored_intervals`:
    plain percentile intervals over 3-5 runs per env covered 76-91% in simulation); none (NaN) at one run per env."""
    rows = []
    for method, matrix in matrices.items():
        matrix = _check_matrix(method, matrix)
        iqm = interquartile_mean(matrix)
        intervals = _NO_INTERVAL
        if matrix.shape[0] >= 2:  # as `stratified_interval`: one run per env has no interval
            (draws,) = stratified_resamples([matrix], cell_rng(seed, "aggregate", method), n_boot)
            boot = stratified_mean_variance(draws)
            floors = _mean_floors(stratified_mean_variance(matrix), boot, level)
            intervals = _floored_intervals(iqm, _iqm_of_resamples(draws), boot[0], floors, level)
        rows.append({"method": method, "iqm": iqm, "mean": float(matrix.mean()), **intervals,
                     "n_envs": matrix.shape[1], "seeds_per_env": matrix.shape[0]})
    return pd.DataFrame(rows, columns=AGGREGATE_COLUMNS)


# ------------------------------------------------------------------------------------- normalized by a reference

#: The columns of `normalized_aggregate_table`: `role` says which row is the normalizer ("reference", 1.0 by
#: construction, no interval) and which are compared with it ("compared").
NORMALIZED_COLUMNS = ["method", "role", *AGGREGATE_COLUMNS[1:]]


def _check_reference(reference: np.ndarray) -> None:
    """Every run of the reference in an env nonzero and of one sign, so no resample's mean can be 0 (or cross it)."""
    for env in range(reference.shape[1]):
        runs = reference[:, env]
        if not (np.all(runs > 0) or np.all(runs < 0)):
            raise ValueError(f"the reference's runs in env column {env} must all be nonzero and of one sign, so that "
                             f"every resample's mean is nonzero; got {runs.tolist()}.")


def _normalize(raw: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Each (..., runs, envs) resample of `raw` over its env's mean in the matching resample of `reference`: the
    normalizer is estimated again in every replicate, so its own uncertainty enters the interval."""
    return raw / reference.mean(axis=-2, keepdims=True)


def normalized_aggregate_table(raw: dict[str, np.ndarray], reference: str, n_boot: int, seed: int = 0,
                               level: float = 0.95) -> pd.DataFrame:
    """IQM and mean of each method's runs over the mean of `raw[reference]`'s runs in the same env.

    Each stratified replicate draws the method's runs and the reference's runs of every env (apart: other training
    runs) and divides by the replicate's own reference mean (`_normalize`), so the normalizer's uncertainty is in the
    interval; the mean's floors are the delta-method t interval of the mean of per-env ratios of means and its
    studentized bootstrap (`ratio_mean_variance`), the IQM widened as in `aggregate_table`.

    `raw`: {method: (runs, envs) raw scores}, all of one shape (the same envs, in the same order); `reference`: the
    key of the normalizer (the baseline), whose runs in each env must share one sign. Its row is 1.0 by construction
    and only shows the scale: role "reference", no interval (NaN), as every row at one run per env.
    """
    if reference not in raw:
        raise ValueError(f"the reference {reference!r} must be one of the methods given, got {list(raw)}.")
    matrices = {method: _check_matrix(method, matrix) for method, matrix in raw.items()}
    ref = matrices[reference]
    if any(m.shape != ref.shape for m in matrices.values()):
        raise ValueError(f"every method needs the reference's (runs, envs) shape {ref.shape}, got "
                         f"{ {k: m.shape for k, m in matrices.items()} }.")
    _check_reference(ref)
    means = ref.mean(axis=0)
    rows = []
    for method, matrix in matrices.items():
        normalized = matrix / means
        iqm = interquartile_mean(normalized)
        intervals = _NO_INTERVAL
        if method != reference and matrix.shape[0] >= 2:
            x, y = stratified_resamples([matrix, ref], cell_rng(seed, "normalized aggregate", method, reference),
                                        n_boot)
            boot = ratio_mean_variance(x, y)
            floors = _mean_floors(ratio_mean_variance(matrix, ref), boot, level)
            intervals = _floored_intervals(iqm, _iqm_of_resamples(_normalize(x, y)), boot[0], floors, level)
        rows.append({"method": method, "role": "reference" if method == reference else "compared", "iqm": iqm,
                     "mean": float(normalized.mean()), **intervals, "n_envs": matrix.shape[1],
                     "seeds_per_env": matrix.shape[0]})
    return pd.DataFrame(rows, columns=NORMALIZED_COLUMNS)


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
    percentile interval (the runs of each method resampled apart, env by env).

    Descriptive: unlike the aggregates' intervals these have no small-sample floor (narrow at 3 runs per env), and no
    verdict reads them.
    """
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
    divided by the mean of the baseline's runs in the same env, so envs of different reward scales can pool.

    The `reward` column is what `by_env_family(..., "reward", ..., normalize_by="baseline")` aggregates (the
    baseline re-drawn in every resample); `normalized_reward` holds that mean fixed, fine for a profile's points.
    """
    sampled = episodes[~episodes["deterministic"].astype(bool)]
    sampled = sampled[(sampled["method"] == "baseline") | (sampled["inference"] == "combined")]
    runs = sampled.groupby(["env", "method", "seed"], as_index=False)["reward"].mean()
    baseline = runs[runs["method"] == "baseline"].groupby("env")["reward"].mean()
    runs = runs[runs["env"].isin(baseline.index)]
    return runs.assign(normalized_reward=runs["reward"] / runs["env"].map(baseline))


def _family(env: str) -> str:
    """MuJoCo or Atari: the aggregates pool each apart, as their seed counts and scales differ."""
    from paper_lib.agents.envs import is_atari

    return "Atari" if is_atari(env) else "MuJoCo"


def by_env_family(scores: pd.DataFrame, value: str, methods: list[str], n_boot: int, seed: int = 0,
                  normalize_by: str | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(aggregates, probabilities of improvement) of `value`, MuJoCo and Atari apart (their seed counts and
    scales differ), each with a `family` column and the envs it pooled.

    `normalize_by` (e.g. "baseline"): `value` is a raw score (each run's reward) and the aggregates are of it over
    that method's mean in the same env, re-normalized in every resample (`normalized_aggregate_table`, with its
    `role` column); a family without that method's runs is left out. Probabilities of improvement are of the raw
    scores: dividing both sides by one env's positive mean changes no comparison. Without it (AUROCs), as before.
    """
    aggregates, improvements = [], []
    for family, part in scores.groupby(scores["env"].map(_family), sort=False):
        present = [m for m in methods if m in set(part["method"])]
        if normalize_by is not None and normalize_by not in set(part["method"]):
            continue
        needed = present if normalize_by is None or normalize_by in present else [normalize_by, *present]
        matrices = score_matrices(part, value, needed)
        if not matrices:
            continue
        envs = ", ".join(complete_envs(part, needed))
        if normalize_by is None:
            table = aggregate_table(matrices, n_boot, seed)
        else:
            table = normalized_aggregate_table(matrices, normalize_by, n_boot, seed)
            table = table[table["method"].isin(present)]
        aggregates.append(table.assign(family=family, envs=envs))
        shown = {m: matrices[m] for m in present}
        improvements.append(improvement_table(shown, n_boot=n_boot, seed=seed).assign(family=family))
    first = AGGREGATE_COLUMNS if normalize_by is None else NORMALIZED_COLUMNS
    columns = ["family", *first, "envs"], ["family", *IMPROVEMENT_COLUMNS]
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

    Descriptive: the bands are pointwise percentile bands without the aggregates' small-sample floor (and, on
    normalized rewards, with the normalizer held fixed). One seed per env has no band (NaN), as the aggregate tables
    have no interval there: resampling one run per env only repeats it.
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
    parts = []
    for family, part in scores.groupby(scores["env"].map(_family), sort=False):
        present = [m for m in methods if m in set(part["method"])]
        matrices = score_matrices(part, value, present)
        if not matrices:
            continue
        grid = profile_taus(matrices) if taus is None else taus
        parts.append(performance_profile(matrices, grid, n_boot, seed).assign(
            family=family, envs=", ".join(complete_envs(part, present))))
    columns = ["family", *PROFILE_COLUMNS, "envs"]
    return pd.concat(parts, ignore_index=True)[columns] if parts else pd.DataFrame(columns=columns)
