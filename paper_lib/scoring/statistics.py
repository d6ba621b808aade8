"""The statistics behind every interval in the tables: the resampling draws and the intervals drawn from them.

One home (issue 39): metrics (`scoring.metrics`), table builders (`scoring.rewards`, `scoring.ood_scores`,
`reporting.paper_tables`, `reporting.aggregates`) and experiments call these instead of resampling or computing
an interval by hand, so each rule is stated once. Nothing here knows what is resampled (rewards, AUROCs, scores).

Draws. A run's states come in clusters (the states of one episode, or of one OOD configuration, are far from
independent), so `cluster_resamples` draws whole clusters; `state_resamples` draws single states, which gives
intervals too narrow for such data. `resample_counts` is the one draw with replacement both build on, and
`mean_replicates` the bootstrap of a mean (one seed's episodes). `stratified_resample` draws the runs of each env
apart (rliable's stratified bootstrap, `reporting.aggregates`; `stratified_resamples` draws many at once), and
the floors of its aggregates (a mean of per-env means, or of per-env ratios of means) are Student's t
(`stratified_t_interval`, `ratio_t_interval`: Welch-Satterthwaite over the envs) and the studentized bootstrap
(`bootstrap_t_interval`). `cell_rng` seeds each table cell on its own.

Seeds, then clusters. A cell that pools training seeds resamples seeds, then clusters within each
(`seed_cluster_replicates`), and its interval (`seed_cluster_ci`) is never narrower than Student's t interval over
the seed estimates (`t_interval`): with 3 seeds, a percentile bootstrap spans about their min-max and covers far
less than 95% (tests/scoring/test_statistics.py simulates it). The same two levels give the reward tables' intervals
(`seed_mean_ci`: `mean_replicates` of each seed's episodes) and the intervals of differences between methods or
measures (`difference_ci`, `seed_mean_difference_ci`; paired where both sides share their resamples, at least
Welch's interval where unpaired).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Hashable, Iterator, Sequence

import numpy as np
import pandas as pd
from scipy.stats import t as student_t

ArrayLike = np.ndarray | list[float] | pd.Series


def check_bootstrap_args(rng: np.random.Generator, n_boot: int, level: float) -> None:
    """The arguments every bootstrap shares, checked where they enter."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}.")
    if int(n_boot) != n_boot or n_boot < 1:
        raise ValueError(f"n_boot must be a positive integer, got {n_boot!r}.")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie strictly between 0 and 1 (e.g. 0.95), got {level!r}.")


def cell_rng(seed: int, *key: Hashable) -> np.random.Generator:
    """A generator for one table cell, from the table's seed and the cell's key.

    Each cell draws its own resamples, so its interval is the same whatever other runs exist
    and in whatever order the cells come: regenerating gives identical numbers.
    """
    return np.random.default_rng([int(seed), zlib.crc32("|".join(map(str, key)).encode())])


# ----------------------------------------------------------------------------- draws


def resample_counts(n: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """(size, n) counts: how often each of n units is drawn in each of `size` resamples of n with replacement."""
    return rng.multinomial(n, np.full(n, 1.0 / n), size=size)


def cluster_labels(clusters: ArrayLike | None, n: int, name: str) -> np.ndarray:
    """One cluster label per state; None: every state its own cluster (the state bootstrap), never shared with the
    other side."""
    if clusters is None:
        return np.char.add(f"{name}-state-", np.arange(n).astype(str))
    labels = np.asarray(clusters).astype(str)
    if labels.shape != (n,):
        raise ValueError(f"{name} must give one cluster label per state ({n}), got shape {labels.shape}.")
    return labels


def cluster_resamples(id_labels: np.ndarray, ood_labels: np.ndarray, rng: np.random.Generator, n_boot: int,
                      chunk: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Weights (how often each state is drawn) of `n_boot` cluster resamples, `chunk` at a time: (w_id, w_ood).

    ID clusters are drawn with replacement (as many as there are), and so are the OOD clusters
    that do not occur on the ID side. An OOD cluster that shares its label with an ID cluster
    (noise OOD states made from that ID episode's states) follows the draw of that ID cluster,
    so dependent ID and OOD states are resampled together.
    """
    id_names, id_index = np.unique(id_labels, return_inverse=True)
    shared = np.isin(ood_labels, id_names)
    own_names, own_index = np.unique(ood_labels[~shared], return_inverse=True)
    for start in range(0, int(n_boot), chunk):
        b = min(chunk, int(n_boot) - start)
        id_counts = resample_counts(id_names.size, b, rng)
        w_ood = np.empty((b, ood_labels.size))
        w_ood[:, shared] = id_counts[:, np.searchsorted(id_names, ood_labels[shared])]
        if own_names.size:
            own_counts = resample_counts(own_names.size, b, rng)
            w_ood[:, ~shared] = own_counts[:, own_index]
        yield id_counts[:, id_index].astype(float), w_ood


def state_resamples(n_id: int, n_ood: int, rng: np.random.Generator, n_boot: int,
                    chunk: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Indices of `n_boot` resamples of single states, `chunk` at a time: ID and OOD states drawn apart.

    They are two independently collected samples, each resample keeping each set's size: pooling them
    would let the class balance drift between replicates.
    """
    for start in range(0, int(n_boot), chunk):
        b = min(chunk, int(n_boot) - start)
        yield rng.integers(0, n_id, size=(b, n_id)), rng.integers(0, n_ood, size=(b, n_ood))


def mean_replicates(values: ArrayLike, rng: np.random.Generator, n_boot: int = 1000) -> np.ndarray:
    """Bootstrap replicates of the mean of `values` (one seed's episodes), resampled with replacement.

    ``values`` is (n,) or (m, n): m aligned rows (episode i of m methods played from the same
    env seed) all resampled with the same draws, so replicate b of every row uses the same
    episodes and differences of rows stay paired. Returns (n_boot,) or (m, n_boot).
    """
    arr = np.asarray(values, dtype=float)
    rows = np.atleast_2d(arr)
    if rows.ndim != 2 or rows.shape[1] == 0 or not np.all(np.isfinite(rows)):
        raise ValueError(f"values must be (n,) or (m, n) finite numbers with n >= 1, got shape {arr.shape}.")
    check_bootstrap_args(rng, n_boot, 0.95)
    n = rows.shape[1]
    counts = resample_counts(n, int(n_boot), rng)
    reps = rows @ counts.T / n
    return reps[0] if arr.ndim == 1 else reps


def stratified_resample(matrix: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """`matrix` (runs, envs) with the runs of each env (column) drawn again with replacement, each env apart."""
    rows = rng.integers(0, matrix.shape[0], size=matrix.shape)
    return np.take_along_axis(matrix, rows, axis=0)


def stratified_replicates(statistic: Callable[..., object], matrices: Sequence[np.ndarray], rng: np.random.Generator,
                          n_boot: int) -> np.ndarray:
    """`statistic` of `n_boot` stratified resamples of `matrices` (each resampled on its own, in the order given)."""
    return np.array([statistic(*(stratified_resample(m, rng) for m in matrices)) for _ in range(int(n_boot))])


def stratified_resamples(matrices: Sequence[np.ndarray], rng: np.random.Generator, n_boot: int) -> list[np.ndarray]:
    """`n_boot` stratified resamples of each matrix at once: one (n_boot, runs, envs) array per matrix, each matrix
    drawn on its own (in the order given), each env's runs apart, as `stratified_resample`.

    One draw per matrix instead of one per replicate (about 80 times faster), so a statistic vectorized over the
    first axis (and a coverage simulation of it) stays fast; its numbers differ from `stratified_replicates`'.
    """
    check_bootstrap_args(rng, n_boot, 0.95)
    out = []
    for matrix in matrices:
        m = np.asarray(matrix)
        rows = rng.integers(0, m.shape[0], size=(int(n_boot), *m.shape))
        out.append(np.take_along_axis(m[None], rows, axis=1))
    return out


# ----------------------------------------------------------------------------- intervals


def percentile_interval(values: np.ndarray, level: float) -> tuple[float, float]:
    """The central `level` percentile interval of bootstrap replicates, NaN replicates left out."""
    alpha = (1.0 - level) / 2.0
    low, high = np.nanquantile(values, [alpha, 1.0 - alpha])
    return float(low), float(high)


def percentile_band(values: np.ndarray, level: float, axis: int | None = None) -> np.ndarray:
    """(low, high) of rliable's percentile interval (np.percentile at 50(1 -+ level)), pointwise along `axis`.

    Kept apart from `percentile_interval` (which skips NaN replicates) since the two spell the quantile level
    differently in its last bits: one formula for both would move the committed aggregate tables.
    """
    return np.percentile(values, [50 * (1 - level), 50 * (1 + level)], axis=axis)


def stratified_interval(replicates: np.ndarray, level: float, runs_per_env: int) -> tuple[float, float]:
    """`percentile_band` of stratified-bootstrap replicates; none (NaN) from one run per env, which resampling only
    repeats: such an aggregate has no interval, and the tables say so."""
    if runs_per_env < 2:
        return float("nan"), float("nan")
    low, high = percentile_band(replicates, level)
    return float(low), float(high)


def t_interval(estimates: ArrayLike, level: float = 0.95) -> tuple[float, float]:
    """Student's t interval of the mean of n >= 2 per-seed estimates: the floor of every interval over seeds."""
    x = np.asarray(estimates, dtype=float)
    if x.ndim != 1 or x.size < 2 or not np.all(np.isfinite(x)):
        raise ValueError(f"t_interval needs two or more finite per-seed estimates, got {x.tolist()}.")
    half = float(student_t.ppf(0.5 + level / 2.0, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return float(x.mean() - half), float(x.mean() + half)


def welch_interval(a: ArrayLike, b: ArrayLike, level: float = 0.95) -> tuple[float, float]:
    """Welch's t interval of mean(a) - mean(b) for two independent samples of seeds (each n >= 2)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se = np.sqrt(va + vb)
    dof = (va + vb) ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1)) if se > 0 else 1.0
    half = float(student_t.ppf(0.5 + level / 2.0, dof) * se)
    return float(a.mean() - b.mean() - half), float(a.mean() - b.mean() + half)


def satterthwaite_interval(estimate: float, variances: ArrayLike, dofs: ArrayLike,
                           level: float = 0.95) -> tuple[float, float]:
    """t interval of an estimate whose variance is a sum of independent components, each estimated with its dof.

    The Welch-Satterthwaite approximation: df = (sum v)^2 / sum(v^2 / dof). Welch's interval is the case of two
    components; a mean of per-env means (components s_e^2 / (n_e E^2), dof n_e - 1) the stratified one. A zero
    variance gives the point itself.
    """
    v, d = np.asarray(variances, dtype=float).ravel(), np.asarray(dofs, dtype=float).ravel()
    if v.shape != d.shape or v.size == 0 or not (np.all(np.isfinite(v)) and np.all(v >= 0) and np.all(d > 0)):
        raise ValueError(f"satterthwaite_interval needs one finite variance >= 0 and one dof > 0 per component, got "
                         f"{v.tolist()} and {d.tolist()}.")
    total = float(v.sum())
    if total == 0.0:
        return float(estimate), float(estimate)
    dof = total ** 2 / float(np.sum(v ** 2 / d))
    half = float(student_t.ppf(0.5 + level / 2.0, dof) * np.sqrt(total))
    return float(estimate - half), float(estimate + half)


def stratified_mean_variance(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(estimate, variance components, their dofs) of the mean of per-env means of (..., runs, envs) matrices.

    Env e adds s_e^2 / (n_e E^2) (s_e: its runs' std, ddof=1) with n_e - 1 dof; leading axes are resamples, so a
    bootstrap gets every replicate's standard error at once.
    """
    m = np.asarray(matrix, dtype=float)
    runs, envs = m.shape[-2:]
    return m.mean(axis=-2).mean(axis=-1), m.var(axis=-2, ddof=1) / runs / envs ** 2, np.full(envs, runs - 1.0)


def ratio_mean_variance(numerator: np.ndarray, denominator: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(estimate, variance components, their dofs) of the mean over envs of mean(numerator_e) / mean(denominator_e),
    (..., runs, envs) matrices of independent runs (a method's rewards over the baseline's mean in each env).

    Delta method per env: var(xbar/ybar) ~ (s_x^2/n_x + r^2 s_y^2/n_y) / ybar^2, r = xbar/ybar, two independent
    components per env (dof n_x - 1 and n_y - 1). Fieller's interval is exact under normality but unbounded once
    ybar is not clearly nonzero; the callers check the denominator's runs share one sign, and this only ever widens
    a bootstrap that re-draws the denominator, which carries the ratio's skew.
    """
    x, y = np.asarray(numerator, dtype=float), np.asarray(denominator, dtype=float)
    (runs_x, envs), runs_y = x.shape[-2:], y.shape[-2]
    ybar = y.mean(axis=-2)
    ratio = x.mean(axis=-2) / ybar
    parts = [x.var(axis=-2, ddof=1) / runs_x / ybar ** 2, ratio ** 2 * y.var(axis=-2, ddof=1) / runs_y / ybar ** 2]
    dofs = np.concatenate([np.full(envs, runs_x - 1.0), np.full(envs, runs_y - 1.0)])
    return ratio.mean(axis=-1), np.concatenate(parts, axis=-1) / envs ** 2, dofs


def _finite_runs(name: str, *matrices: np.ndarray) -> list[np.ndarray]:
    """The matrices as floats, or one ValueError: a t floor needs finite runs, two or more per env, the same envs."""
    arrays = [np.asarray(m, dtype=float) for m in matrices]
    if any(m.ndim != 2 or m.shape[0] < 2 or m.shape[1] == 0 or not np.all(np.isfinite(m)) for m in arrays) or len(
            {m.shape[1] for m in arrays}) != 1:
        raise ValueError(f"{name} needs finite (runs, envs) matrices over the same envs with two or more runs per env, "
                         f"got shapes {[m.shape for m in arrays]}.")
    return arrays


def stratified_t_interval(matrix: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Student's t floor of the mean of per-env means of a (runs, envs) matrix, runs of each env independent.

    se = sqrt(sum_e s_e^2 / n_e) / E, df by Welch-Satterthwaite over the envs (`stratified_mean_variance`): the
    stratified counterpart of `t_interval`, which a stratified percentile bootstrap over 3 runs per env falls short
    of (it spans about each env's min-max, as with seeds).
    """
    (m,) = _finite_runs("stratified_t_interval", matrix)
    estimate, variances, dofs = stratified_mean_variance(m)
    return satterthwaite_interval(float(estimate), variances, dofs, level)


def ratio_t_interval(numerator: np.ndarray, denominator: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """t floor of the mean over envs of per-env ratios of means (`ratio_mean_variance`, df by Welch-Satterthwaite
    over its 2E components); the denominator's mean must be nonzero in every env."""
    x, y = _finite_runs("ratio_t_interval", numerator, denominator)
    if np.any(y.mean(axis=0) == 0):
        raise ValueError("ratio_t_interval needs a nonzero denominator mean in every env.")
    estimate, variances, dofs = ratio_mean_variance(x, y)
    return satterthwaite_interval(float(estimate), variances, dofs, level)


def bootstrap_t_interval(estimate: float, se: float, replicates: np.ndarray, replicate_ses: np.ndarray,
                         level: float = 0.95) -> tuple[float, float]:
    """The studentized (bootstrap-t) interval: estimate - q(1 - a) se, estimate - q(a) se, q the quantiles of
    (replicate - estimate) / replicate_se.

    Second-order accurate where t and the percentile interval are first-order (Hall 1988; Efron & Tibshirani 1993,
    ch. 12): it follows the skew of the runs, which at 3-5 runs per env leaves t short on the long side. Replicates
    whose se is 0 (every env's runs drawn alike) carry no studentized value and are left out; with none left, or
    se 0, the point itself (a floor that widens nothing).
    """
    reps, ses = np.asarray(replicates, dtype=float), np.asarray(replicate_ses, dtype=float)
    keep = ses > 0
    if se <= 0 or not keep.any():
        return float(estimate), float(estimate)
    alpha = (1.0 - level) / 2.0
    low_q, high_q = np.quantile((reps[keep] - estimate) / ses[keep], [alpha, 1.0 - alpha])
    return float(estimate - high_q * se), float(estimate - low_q * se)


def _widen(interval: tuple[float, float], floor: tuple[float, float]) -> tuple[float, float]:
    return min(interval[0], floor[0]), max(interval[1], floor[1])


# ----------------------------------------------------------------------------- seeds, then clusters


def seed_cluster_replicates(replicates: Sequence[np.ndarray], rng: np.random.Generator,
                            n_boot: int = 1000) -> np.ndarray:
    """Bootstrap replicates of a mean over training seeds: resample seeds, then clusters within each.

    ``replicates[s]`` are seed s's cluster-bootstrap replicates (`metrics.cluster_bootstrap_auroc`, or
    `mean_replicates` of its episodes). Each outer replicate draws as many seeds as there are,
    with replacement, and for each draw one of that seed's replicates; their mean is the
    replicate. With one seed these are that seed's own replicates (nothing to resample above them).
    """
    reps = _seed_replicates(replicates)
    if len(reps) == 1:
        return reps[0]
    seeds = rng.integers(0, len(reps), size=(int(n_boot), len(reps)))
    return _pick_per_seed(reps, seeds, rng)


def _seed_replicates(replicates: Sequence[np.ndarray]) -> list[np.ndarray]:
    reps = [np.asarray(r, dtype=float) for r in replicates]
    if not reps or any(r.ndim != 1 or r.size == 0 for r in reps):
        raise ValueError("replicates must be a non-empty list of non-empty 1-D arrays, one per training seed.")
    return reps


def _pick_per_seed(reps: list[np.ndarray], seeds: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Mean over each row of drawn `seeds` of one randomly picked replicate of that seed (NaN-padded sizes)."""
    picks = rng.random(size=seeds.shape)
    sizes = np.array([r.size for r in reps])
    stacked = np.full((len(reps), sizes.max()), np.nan)
    for i, r in enumerate(reps):
        stacked[i, :r.size] = r
    return stacked[seeds, (picks * sizes[seeds]).astype(int)].mean(axis=1)


def _seed_estimates(reps: list[np.ndarray], estimates: ArrayLike | None) -> np.ndarray:
    est = np.array([r.mean() for r in reps]) if estimates is None else np.asarray(estimates, dtype=float)
    if est.shape != (len(reps),):
        raise ValueError(f"estimates must give one number per training seed ({len(reps)}), got shape {est.shape}.")
    return est


def seed_cluster_ci(replicates: Sequence[np.ndarray], rng: np.random.Generator, n_boot: int = 1000,
                    level: float = 0.95, estimates: ArrayLike | None = None) -> tuple[float, float]:
    """Interval of the mean over training seeds: resample seeds, then clusters within each.

    The percentile interval of `seed_cluster_replicates`, widened where needed to Student's t
    interval over the seeds' `estimates` (each seed's own number; by default the mean of its
    replicates): the hierarchical bootstrap may add the within-seed part, never go below t.
    With one seed this is that seed's own cluster interval (episodes or states of one run only).
    """
    reps = _seed_replicates(replicates)
    interval = percentile_interval(seed_cluster_replicates(reps, rng, n_boot=n_boot), level)
    if len(reps) < 2:
        return interval
    return _widen(interval, t_interval(_seed_estimates(reps, estimates), level))


#: How the replicates of two compared quantities relate (`seed_cluster_difference`).
PAIRINGS = ("paired", "seeds", "unpaired")


def seed_cluster_difference(a: Sequence[np.ndarray], b: Sequence[np.ndarray], rng: np.random.Generator,
                            pairing: str, n_boot: int = 1000) -> np.ndarray:
    """Bootstrap replicates of mean(a) - mean(b), each a mean over training seeds of per-seed replicates.

    - "paired": a[s] and b[s] come from the same seed and replicate i of both from the same
      resample (same episodes, same clusters): seeds are drawn once and each seed's difference
      replicates are used, so what both share cancels (identical data give exactly 0).
    - "seeds": the same seeds (a[s] and b[s] of one run) but independent resamples within it:
      seeds drawn once, a replicate picked for each side on its own.
    - "unpaired": two independent samples (other runs, other seeds): each side is resampled on
      its own and the replicates are matched at random, never by their order.
    """
    a, b = _seed_replicates(a), _seed_replicates(b)
    if pairing not in PAIRINGS:
        raise ValueError(f"pairing must be one of {PAIRINGS}, got {pairing!r}.")
    if pairing != "unpaired" and len(a) != len(b):
        raise ValueError(f"a {pairing} difference needs the same seeds on both sides, got {len(a)} and {len(b)}.")
    if pairing == "paired":
        if any(x.size != y.size for x, y in zip(a, b)):
            raise ValueError("paired replicates must have the same number per seed on both sides.")
        return seed_cluster_replicates([x - y for x, y in zip(a, b)], rng, n_boot=n_boot)
    if pairing == "seeds" and len(a) > 1:
        seeds = rng.integers(0, len(a), size=(int(n_boot), len(a)))
        return _pick_per_seed(a, seeds, rng) - _pick_per_seed(b, seeds, rng)
    va, vb = seed_cluster_replicates(a, rng, n_boot=n_boot), seed_cluster_replicates(b, rng, n_boot=n_boot)
    return va[rng.integers(0, va.size, size=int(n_boot))] - vb[rng.integers(0, vb.size, size=int(n_boot))]


def difference_ci(a: Sequence[np.ndarray], b: Sequence[np.ndarray], rng: np.random.Generator, pairing: str,
                  n_boot: int = 1000, level: float = 0.95, estimates_a: ArrayLike | None = None,
                  estimates_b: ArrayLike | None = None) -> tuple[float, float]:
    """Interval of mean(a) - mean(b) over training seeds (see `seed_cluster_difference`), at least Student's t.

    The bootstrap's percentile interval, widened where needed to t over the per-seed differences
    (paired and same-seed sides, n >= 2) or to Welch's interval (unpaired sides, each n >= 2).
    `estimates_*` are each seed's own number (default: the mean of its replicates).
    """
    check_bootstrap_args(rng, n_boot, level)
    interval = percentile_interval(seed_cluster_difference(a, b, rng, pairing, n_boot=n_boot), level)
    reps_a, reps_b = _seed_replicates(a), _seed_replicates(b)
    est_a, est_b = _seed_estimates(reps_a, estimates_a), _seed_estimates(reps_b, estimates_b)
    if pairing != "unpaired" and len(reps_a) >= 2:
        return _widen(interval, t_interval(est_a - est_b, level))
    if pairing == "unpaired" and len(reps_a) >= 2 and len(reps_b) >= 2:
        return _widen(interval, welch_interval(est_a, est_b, level))
    return interval


# ----------------------------------------------------------------------------- means over seeds of episode means


def seed_means(groups: Sequence[np.ndarray]) -> np.ndarray:
    """Each seed's mean of its values (episodes): the per-seed estimates a mean over seeds averages."""
    return np.array([np.asarray(g, dtype=float).mean() for g in groups])


def seed_mean_ci(groups: Sequence[np.ndarray], rng: np.random.Generator, n_boot: int,
                 level: float = 0.95) -> tuple[float, float]:
    """Interval of the mean over seeds of each seed's mean (`groups[s]`: seed s's episodes).

    Two-level bootstrap: the seeds, then the episodes within each drawn seed (`seed_cluster_ci` of
    each seed's `mean_replicates`), never narrower than Student's t over the seed means; with one
    seed, the episodes of that one run only.
    """
    per_seed = [mean_replicates(g, rng, n_boot) for g in groups]
    return seed_cluster_ci(per_seed, rng, n_boot=n_boot, level=level, estimates=seed_means(groups))


def seed_mean_difference_ci(a: Sequence[np.ndarray], b: Sequence[np.ndarray], rng: np.random.Generator,
                            pairing: str, n_boot: int, level: float = 0.95) -> tuple[float, float]:
    """Interval of mean(a) - mean(b), each the mean over seeds of each seed's mean (`a[s]`: seed s's episodes).

    "paired": a[s][i] and b[s][i] are alike (episode i of both from the same seeded env), so both
    sides are resampled with the same draws (`mean_replicates` of the stacked pair); otherwise
    each side's episodes are resampled on their own. See `difference_ci` for the seed level.
    """
    if pairing == "paired":
        if len(a) != len(b) or any(np.size(x) != np.size(y) for x, y in zip(a, b)):
            raise ValueError("paired sides need the same seeds and the same number of episodes per seed.")
        pairs = [np.stack([x, y]) for x, y in zip(a, b)]
        reps = [mean_replicates(p, rng, n_boot) for p in pairs]
        return difference_ci([r[0] for r in reps], [r[1] for r in reps], rng, "paired", n_boot, level,
                             estimates_a=[p[0].mean() for p in pairs], estimates_b=[p[1].mean() for p in pairs])
    reps_a = [mean_replicates(x, rng, n_boot) for x in a]
    reps_b = [mean_replicates(y, rng, n_boot) for y in b]
    return difference_ci(reps_a, reps_b, rng, pairing, n_boot, level, estimates_a=seed_means(a),
                         estimates_b=seed_means(b))


def seed_mean_std(df: pd.DataFrame, keys: list[str], value: str, seed: str = "seed") -> pd.DataFrame:
    """Per cell (`keys`): the mean over seeds of each seed's mean `value`, their std across seeds (NaN with one seed)
    and n_seeds; beside them row_std and n_rows, the std and count of the cell's rows themselves (all seeds pooled)."""
    per_seed = df.groupby([*keys, seed])[value].mean().reset_index()
    out = per_seed.groupby(keys)[value].agg(mean="mean", std="std", n_seeds="count").reset_index()
    rows = df.groupby(keys)[value].agg(row_std="std", n_rows="count").reset_index()
    return out.merge(rows, on=keys)


def mc_standard_error(scoring_std: ArrayLike, n_scoring_seeds: ArrayLike) -> float:
    """The Monte Carlo standard error of a mean over runs of each run's mean over its scoring seeds.

    A stochastic method's (MC Dropout / DropConnect) run estimate is the mean over m scoring seeds, whose spread s
    each run's metrics.csv keeps (`auroc_scoring_std`, the population std, ddof=0): that run's error is
    s / sqrt(m - 1), and the mean of n runs, their draws being independent, has sqrt(sum of their squares) / n. A
    run scored once with no spread (a deterministic method or detector) adds 0; a stochastic run scored once has an
    unknown error (NaN), and so has the mean.
    """
    s = np.asarray(scoring_std, dtype=float)
    m = np.asarray(n_scoring_seeds, dtype=float)
    if s.shape != m.shape or s.size == 0:
        raise ValueError(f"mc_standard_error needs one scoring std and one scoring-seed count per run, got {s.shape} "
                         f"and {m.shape}")
    with np.errstate(divide="ignore", invalid="ignore"):
        per_run = np.where(m > 1, s / np.sqrt(m - 1), np.where(s == 0, 0.0, np.nan))
    return float(np.sqrt(np.sum(per_run**2)) / s.size)


def difference_mc_standard_error(a: float, b: float) -> float:
    """The MC standard error of a difference of two estimates, their MC draws taken as independent."""
    return float(np.hypot(a, b))
