"""OOD detection metrics.

Convention used everywhere in this module: **OOD states are the positive class**
(label 1), ID states the negative class (label 0), and the uncertainty is the score
(higher = more likely OOD). "FPR@95" therefore means: the fraction of ID states
flagged as OOD when the threshold is set so that 95% of OOD states are flagged
(OpenOOD's definition). Libraries that take ID as positive report a different number
under the same name.

Confidence intervals: a run's states come in clusters (the states of one episode, or of
one OOD configuration, are far from independent), so `cluster_bootstrap_auroc` resamples
whole clusters; resampling single states (`bootstrap_auroc_ci`) gives intervals that are
too narrow for such data. `seed_cluster_ci` combines runs of several training seeds:
resample seeds, then clusters within each, and never reports less than Student's t interval over
the seed estimates (`t_interval`): with 3 seeds, a percentile bootstrap spans about their min-max
and covers far less than 95% (tests/test_table_statistics.py simulates it). The same two levels give the reward tables'
intervals (`mean_replicates` of each seed's episodes) and the intervals of differences
between methods or measures (`difference_ci`, paired where both sides share their resamples).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import rankdata
from scipy.stats import t as student_t
from sklearn.metrics import average_precision_score, roc_auc_score, roc_curve

ArrayLike = np.ndarray | list[float] | pd.Series


def _as_scores(scores: ArrayLike, name: str) -> np.ndarray:
    """Return ``scores`` as a finite 1-D float array, or raise naming the input."""
    arr = np.asarray(scores, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array of per-state scores, got shape {arr.shape}; flatten it first.")
    if arr.size == 0:
        raise ValueError(f"{name} is empty; at least one state is needed in both the ID and the OOD set.")
    if not np.all(np.isfinite(arr)):
        bad = int(np.sum(~np.isfinite(arr)))
        raise ValueError(f"{name} contains {bad} NaN/inf value(s); drop or fix those states before scoring.")
    return arr


def _labels_and_scores(id_scores: ArrayLike, ood_scores: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Stack ID (label 0) and OOD (label 1, the positive class) into y and s."""
    id_s = _as_scores(id_scores, "id_scores")
    ood_s = _as_scores(ood_scores, "ood_scores")
    y = np.concatenate([np.zeros(id_s.size, dtype=int), np.ones(ood_s.size, dtype=int)])
    return y, np.concatenate([id_s, ood_s])


def detection_metrics(id_scores: ArrayLike, ood_scores: ArrayLike) -> dict[str, float | int]:
    """Threshold-free and thresholded OOD detection metrics, OOD = positive class.

    Returns auroc, aupr_out (OOD positive), aupr_in (ID positive, score negated),
    fpr_at_95_tpr (smallest FPR whose TPR >= 0.95), detection_error
    (min over thresholds of 0.5 * (1 - TPR) + 0.5 * FPR), n_id and n_ood.
    """
    y, s = _labels_and_scores(id_scores, ood_scores)
    fpr, tpr, _ = roc_curve(y, s, drop_intermediate=False)
    return {
        "auroc": float(roc_auc_score(y, s)),
        "aupr_out": float(average_precision_score(y, s)),
        "aupr_in": float(average_precision_score(1 - y, -s)),
        "fpr_at_95_tpr": float(fpr[tpr >= 0.95].min()),
        "detection_error": float(np.min(0.5 * (1.0 - tpr) + 0.5 * fpr)),
        "n_id": int((y == 0).sum()),
        "n_ood": int((y == 1).sum()),
    }


def roc_points(id_scores: ArrayLike, ood_scores: ArrayLike, drop_intermediate: bool = True) -> pd.DataFrame:
    """ROC curve (OOD = positive) as a tidy frame with columns fpr, tpr, threshold.

    The first row is sklearn's (0, 0) point with threshold +inf; intermediate
    collinear points are dropped by default because plots do not need them.
    """
    y, s = _labels_and_scores(id_scores, ood_scores)
    fpr, tpr, thr = roc_curve(y, s, drop_intermediate=drop_intermediate)
    return pd.DataFrame({"fpr": fpr, "tpr": tpr, "threshold": thr})


def _auroc_from_ranks(id_s: np.ndarray, ood_s: np.ndarray) -> np.ndarray:
    """Row-wise AUROC (Mann-Whitney U / (n_id * n_ood), ties count 1/2) for 2-D score batches."""
    n_id, n_ood = id_s.shape[1], ood_s.shape[1]
    ranks = rankdata(np.concatenate([id_s, ood_s], axis=1), method="average", axis=1)
    u = ranks[:, n_id:].sum(axis=1) - n_ood * (n_ood + 1) / 2.0
    return u / (n_id * n_ood)


def bootstrap_auroc_ci(
    id_scores: ArrayLike,
    ood_scores: ArrayLike,
    rng: np.random.Generator,
    n_boot: int = 1000,
    level: float = 0.95,
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the AUROC (OOD = positive).

    ID and OOD scores are resampled separately (with replacement, each set keeping
    its size) because they are two independently collected samples; pooling them
    would let the class balance drift between replicates.
    """
    id_s = _as_scores(id_scores, "id_scores")
    ood_s = _as_scores(ood_scores, "ood_scores")
    _check_bootstrap_args(rng, n_boot, level)
    n = id_s.size + ood_s.size
    chunk = max(1, 4_000_000 // n)  # bound memory to a few 10 MB per batch of replicates
    aucs = []
    for start in range(0, int(n_boot), chunk):
        b = min(chunk, int(n_boot) - start)
        id_b = id_s[rng.integers(0, id_s.size, size=(b, id_s.size))]
        ood_b = ood_s[rng.integers(0, ood_s.size, size=(b, ood_s.size))]
        aucs.append(_auroc_from_ranks(id_b, ood_b))
    alpha = (1.0 - level) / 2.0
    low, high = np.quantile(np.concatenate(aucs), [alpha, 1.0 - alpha])
    return float(low), float(high)


def _weighted_aurocs(id_s: np.ndarray, ood_s: np.ndarray, w_id: np.ndarray, w_ood: np.ndarray) -> np.ndarray:
    """AUROC of each row's weighted sample (weights = how often a state was drawn), ties counting 1/2.

    One sort for all rows: per distinct score value, the OOD weight there times the ID weight
    below it (plus half the ID weight at it), summed and normalized.
    """
    scores = np.concatenate([id_s, ood_s])
    order = np.argsort(scores, kind="stable")
    ordered = scores[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    is_ood = order >= id_s.size
    weights = np.concatenate([w_id, w_ood], axis=1)[:, order]
    at_id = np.add.reduceat(np.where(is_ood, 0.0, weights), starts, axis=1)
    at_ood = np.add.reduceat(np.where(is_ood, weights, 0.0), starts, axis=1)
    below = np.cumsum(at_id, axis=1) - at_id
    u = (at_ood * (below + 0.5 * at_id)).sum(axis=1)
    return u / (at_id.sum(axis=1) * at_ood.sum(axis=1))


def _score_rows(scores: ArrayLike, name: str) -> np.ndarray:
    """(S, n) scores, one row per scoring seed; a 1-D array is one seed."""
    arr = np.asarray(scores, dtype=float)
    if arr.ndim == 1:
        return _as_scores(arr, name)[None]
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise ValueError(f"{name} must be (n,) or (scoring seeds, n) scores, got shape {arr.shape}.")
    for row in arr:
        _as_scores(row, name)
    return arr


def _cluster_labels(clusters: ArrayLike | None, n: int, name: str) -> np.ndarray:
    if clusters is None:  # every state its own cluster (the state bootstrap), never shared with the other side
        return np.char.add(f"{name}-state-", np.arange(n).astype(str))
    labels = np.asarray(clusters).astype(str)
    if labels.shape != (n,):
        raise ValueError(f"{name} must give one cluster label per state ({n}), got shape {labels.shape}.")
    return labels


@dataclass
class AurocInterval:
    """A bootstrap interval of the AUROC, with its replicates (to combine runs of several seeds)."""

    low: float
    high: float
    replicates: np.ndarray


def cluster_bootstrap_auroc(
    id_scores: ArrayLike,
    ood_scores: ArrayLike,
    id_clusters: ArrayLike | None,
    ood_clusters: ArrayLike | None,
    rng: np.random.Generator,
    n_boot: int = 1000,
    level: float = 0.95,
) -> AurocInterval:
    """Percentile interval of the AUROC when whole clusters (episodes, configurations) are resampled.

    ID clusters are drawn with replacement (as many as there are), and so are the OOD clusters
    that do not occur on the ID side. An OOD cluster that shares its label with an ID cluster
    (noise OOD states made from that ID episode's states) follows the draw of that ID cluster,
    so dependent ID and OOD states are resampled together. Clusters None = each state its own.
    Scores may be (S, n): S scoring seeds of a stochastic method scored on the same states;
    each replicate is then the mean AUROC over the S seeds (the same clusters for all).
    """
    id_s, ood_s = _score_rows(id_scores, "id_scores"), _score_rows(ood_scores, "ood_scores")
    if id_s.shape[0] != ood_s.shape[0]:
        raise ValueError(f"id_scores has {id_s.shape[0]} scoring seeds but ood_scores {ood_s.shape[0]}; "
                         "give both the same.")
    _check_bootstrap_args(rng, n_boot, level)
    id_labels = _cluster_labels(id_clusters, id_s.shape[1], "id_clusters")
    ood_labels = _cluster_labels(ood_clusters, ood_s.shape[1], "ood_clusters")
    id_names, id_index = np.unique(id_labels, return_inverse=True)
    shared = np.isin(ood_labels, id_names)
    own_names, own_index = np.unique(ood_labels[~shared], return_inverse=True)
    n = id_s.shape[1] + ood_s.shape[1]
    chunk = max(1, 2_000_000 // n)
    replicates = []
    for start in range(0, int(n_boot), chunk):
        b = min(chunk, int(n_boot) - start)
        id_counts = rng.multinomial(id_names.size, np.full(id_names.size, 1.0 / id_names.size), size=b)
        w_ood = np.empty((b, ood_s.shape[1]))
        w_ood[:, shared] = id_counts[:, np.searchsorted(id_names, ood_labels[shared])]
        if own_names.size:
            own_counts = rng.multinomial(own_names.size, np.full(own_names.size, 1.0 / own_names.size), size=b)
            w_ood[:, ~shared] = own_counts[:, own_index]
        w_id = id_counts[:, id_index].astype(float)
        aurocs = [_weighted_aurocs(i, o, w_id, w_ood) for i, o in zip(id_s, ood_s)]
        replicates.append(np.mean(aurocs, axis=0))
    reps = np.concatenate(replicates)
    alpha = (1.0 - level) / 2.0
    low, high = np.nanquantile(reps, [alpha, 1.0 - alpha])
    return AurocInterval(float(low), float(high), reps)


def seed_cluster_replicates(replicates: Sequence[np.ndarray], rng: np.random.Generator,
                            n_boot: int = 1000) -> np.ndarray:
    """Bootstrap replicates of a mean over training seeds: resample seeds, then clusters within each.

    ``replicates[s]`` are seed s's cluster-bootstrap replicates (`cluster_bootstrap_auroc`, or
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


def _percentile_interval(values: np.ndarray, level: float) -> tuple[float, float]:
    alpha = (1.0 - level) / 2.0
    low, high = np.nanquantile(values, [alpha, 1.0 - alpha])
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


def _widen(interval: tuple[float, float], floor: tuple[float, float]) -> tuple[float, float]:
    return min(interval[0], floor[0]), max(interval[1], floor[1])


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
    interval = _percentile_interval(seed_cluster_replicates(reps, rng, n_boot=n_boot), level)
    if len(reps) < 2:
        return interval
    return _widen(interval, t_interval(_seed_estimates(reps, estimates), level))


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
    _check_bootstrap_args(rng, n_boot, 0.95)
    n = rows.shape[1]
    counts = rng.multinomial(n, np.full(n, 1.0 / n), size=int(n_boot))
    reps = rows @ counts.T / n
    return reps[0] if arr.ndim == 1 else reps


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
    _check_bootstrap_args(rng, n_boot, level)
    interval = _percentile_interval(seed_cluster_difference(a, b, rng, pairing, n_boot=n_boot), level)
    reps_a, reps_b = _seed_replicates(a), _seed_replicates(b)
    est_a, est_b = _seed_estimates(reps_a, estimates_a), _seed_estimates(reps_b, estimates_b)
    if pairing != "unpaired" and len(reps_a) >= 2:
        return _widen(interval, t_interval(est_a - est_b, level))
    if pairing == "unpaired" and len(reps_a) >= 2 and len(reps_b) >= 2:
        return _widen(interval, welch_interval(est_a, est_b, level))
    return interval


def measure_metrics(
    id_scores: ArrayLike,
    ood_scores: ArrayLike,
    rng: np.random.Generator,
    n_boot: int = 1000,
    level: float = 0.95,
    id_clusters: ArrayLike | None = None,
    ood_clusters: ArrayLike | None = None,
) -> tuple[dict[str, float | int | str], np.ndarray]:
    """One measure's row of metrics (means over scoring seeds) and its AUROC bootstrap replicates.

    Scores are (n,) or (S, n) for S scoring seeds. The row: auroc, aupr_out, aupr_in,
    fpr_at_95_tpr, detection_error (each the mean over scoring seeds), the AUROC's spread over
    scoring seeds (auroc_scoring_std/min/max), its interval (auroc_ci_low/high) from the
    cluster bootstrap (ci="cluster"), or from the state bootstrap without clusters (ci="state").
    """
    id_s, ood_s = _score_rows(id_scores, "id_scores"), _score_rows(ood_scores, "ood_scores")
    per_seed = pd.DataFrame([detection_metrics(i, o) for i, o in zip(id_s, ood_s)])
    interval = cluster_bootstrap_auroc(id_s, ood_s, id_clusters, ood_clusters, rng, n_boot=n_boot, level=level)
    clustered = id_clusters is not None or ood_clusters is not None
    row: dict[str, float | int | str] = {
        name: float(per_seed[name].mean()) for name in ("auroc", "aupr_out", "aupr_in", "fpr_at_95_tpr",
                                                         "detection_error")}
    row.update(auroc_ci_low=interval.low, auroc_ci_high=interval.high, ci="cluster" if clustered else "state",
               auroc_scoring_std=float(per_seed["auroc"].std(ddof=0)), auroc_scoring_min=float(per_seed["auroc"].min()),
               auroc_scoring_max=float(per_seed["auroc"].max()), n_scoring_seeds=int(len(per_seed)),
               n_id=int(id_s.shape[1]), n_ood=int(ood_s.shape[1]),
               n_id_clusters=int(np.unique(_cluster_labels(id_clusters, id_s.shape[1], "id_clusters")).size),
               n_ood_clusters=int(np.unique(_cluster_labels(ood_clusters, ood_s.shape[1], "ood_clusters")).size))
    return row, interval.replicates


def metrics_table(
    scores: Mapping[str, tuple[ArrayLike, ArrayLike]],
    rng: np.random.Generator,
    n_boot: int = 1000,
    level: float = 0.95,
    id_clusters: ArrayLike | None = None,
    ood_clusters: ArrayLike | None = None,
) -> pd.DataFrame:
    """One row per uncertainty measure: all detection metrics plus the AUROC bootstrap CI.

    ``scores`` maps a measure name (e.g. "value_std") to its (ID, OOD) score arrays, each
    (n,) or (scoring seeds, n). Rows keep the mapping's order; see `measure_metrics` for the
    columns. With cluster labels (shared by every measure), the CI resamples whole clusters.
    """
    if not isinstance(scores, Mapping) or len(scores) == 0:
        raise ValueError("scores must be a non-empty dict {measure name: (id_scores, ood_scores)}.")
    rows = []
    for measure, pair in scores.items():
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise ValueError(f"scores[{measure!r}] must be a pair (id_scores, ood_scores), got {type(pair).__name__}.")
        try:
            row, _ = measure_metrics(*pair, rng, n_boot=n_boot, level=level, id_clusters=id_clusters,
                                     ood_clusters=ood_clusters)
        except ValueError as err:
            raise ValueError(f"scores[{measure!r}]: {err}") from None
        rows.append({"measure": measure, **row})
    return pd.DataFrame(rows)


def _check_bootstrap_args(rng: np.random.Generator, n_boot: int, level: float) -> None:
    """The arguments every bootstrap here shares, checked where they enter."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}.")
    if int(n_boot) != n_boot or n_boot < 1:
        raise ValueError(f"n_boot must be a positive integer, got {n_boot!r}.")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie strictly between 0 and 1 (e.g. 0.95), got {level!r}.")
