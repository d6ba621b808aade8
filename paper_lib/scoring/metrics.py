"""OOD detection metrics.

Convention used everywhere in this module: **OOD states are the positive class**
(label 1), ID states the negative class (label 0), and the uncertainty is the score
(higher = more likely OOD). "FPR@95" therefore means: the fraction of ID states
flagged as OOD when the threshold is set so that 95% of OOD states are flagged
(OpenOOD's definition). Libraries that take ID as positive report a different number
under the same name.

The AUROC's bootstrap replicates are computed here (the AUROC of each resample: from ranks, or of
the weighted sample a cluster resample makes); what is drawn (whole clusters, or single states), the
intervals, and the combination of several training seeds live in `statistics`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import rankdata
from sklearn.metrics import average_precision_score, roc_auc_score, roc_curve

from paper_lib.scoring.statistics import (ArrayLike, check_bootstrap_args, cluster_labels, cluster_resamples,
                                          percentile_interval, state_resamples)


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


def auroc(id_scores: ArrayLike, ood_scores: ArrayLike) -> float:
    """ROC-AUC, OOD = positive: how often an OOD state scores above an ID state (ties count 1/2)."""
    return _auroc(*_labels_and_scores(id_scores, ood_scores))


def _auroc(y: np.ndarray, s: np.ndarray) -> float:
    return float(roc_auc_score(y, s))


def detection_metrics(id_scores: ArrayLike, ood_scores: ArrayLike) -> dict[str, float | int]:
    """Threshold-free and thresholded OOD detection metrics, OOD = positive class.

    Returns auroc, aupr_out (OOD positive), aupr_in (ID positive, score negated),
    fpr_at_95_tpr (smallest FPR whose TPR >= 0.95), detection_error
    (min over thresholds of 0.5 * (1 - TPR) + 0.5 * FPR), n_id and n_ood.
    """
    y, s = _labels_and_scores(id_scores, ood_scores)
    fpr, tpr, _ = roc_curve(y, s, drop_intermediate=False)
    return {
        "auroc": _auroc(y, s),
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
    """Percentile bootstrap confidence interval of the AUROC (OOD = positive), single states resampled.

    ID and OOD scores are resampled apart (`statistics.state_resamples`). For clustered states
    (episodes, configurations) this is too narrow: use `cluster_bootstrap_auroc`.
    """
    id_s = _as_scores(id_scores, "id_scores")
    ood_s = _as_scores(ood_scores, "ood_scores")
    check_bootstrap_args(rng, n_boot, level)
    chunk = max(1, 4_000_000 // (id_s.size + ood_s.size))  # bound memory to a few 10 MB per batch of replicates
    aucs = [_auroc_from_ranks(id_s[id_idx], ood_s[ood_idx])
            for id_idx, ood_idx in state_resamples(id_s.size, ood_s.size, rng, n_boot, chunk)]
    return percentile_interval(np.concatenate(aucs), level)


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

    The clusters are drawn by `statistics.cluster_resamples` (an OOD cluster sharing its label with an
    ID cluster follows that cluster's draw); clusters None = each state its own.
    Scores may be (S, n): S scoring seeds of a stochastic method scored on the same states;
    each replicate is then the mean AUROC over the S seeds (the same clusters for all).
    """
    id_s, ood_s = _score_rows(id_scores, "id_scores"), _score_rows(ood_scores, "ood_scores")
    if id_s.shape[0] != ood_s.shape[0]:
        raise ValueError(f"id_scores has {id_s.shape[0]} scoring seeds but ood_scores {ood_s.shape[0]}; "
                         "give both the same.")
    check_bootstrap_args(rng, n_boot, level)
    id_labels = cluster_labels(id_clusters, id_s.shape[1], "id_clusters")
    ood_labels = cluster_labels(ood_clusters, ood_s.shape[1], "ood_clusters")
    chunk = max(1, 2_000_000 // (id_s.shape[1] + ood_s.shape[1]))
    replicates = []
    for w_id, w_ood in cluster_resamples(id_labels, ood_labels, rng, n_boot, chunk):
        aurocs = [_weighted_aurocs(i, o, w_id, w_ood) for i, o in zip(id_s, ood_s)]
        replicates.append(np.mean(aurocs, axis=0))
    reps = np.concatenate(replicates)
    return AurocInterval(*percentile_interval(reps, level), reps)


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
               n_id_clusters=int(np.unique(cluster_labels(id_clusters, id_s.shape[1], "id_clusters")).size),
               n_ood_clusters=int(np.unique(cluster_labels(ood_clusters, ood_s.shape[1], "ood_clusters")).size))
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



# --------------------------------------------------------------- PEDM's protocol: per-step labels


def _per_step(scores: ArrayLike, labels: ArrayLike, episodes: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = _as_scores(scores, "scores")
    y, ep = np.asarray(labels), np.asarray(episodes)
    if y.shape != s.shape or ep.shape != s.shape:
        raise ValueError(f"scores {s.shape}, labels {y.shape} and episodes {ep.shape} need one entry per step each.")
    if not np.isin(y, (0, 1)).all():
        raise ValueError("labels must be 0 (before the injection) or 1 (from it on).")
    return s, y.astype(int), ep


def injection_metrics(scores: ArrayLike, labels: ArrayLike, episodes: ArrayLike,
                      rng: np.random.Generator | None = None, n_boot: int = 1000) -> dict[str, float | int | str]:
    """PEDM's metrics of one (kind, severity): AUROC, AP (``aupr_out``), FPR@95 on the pooled per-step scores.

    As PEDM (``oodd_runner.py`` l. 140-149), an episode that ended before its injection is left out.
    With ``rng``, the AUROC also gets our cluster-bootstrap interval, clusters = episodes (each side's
    steps resampled by whole episodes; see `measure_metrics` for the columns).
    """
    s, y, ep = _per_step(scores, labels, episodes)
    injected = np.unique(ep[y == 1])
    keep = np.isin(ep, injected)
    dropped = int(np.unique(ep).size - injected.size)
    if not (y[keep] == 0).any() or not (y[keep] == 1).any():
        raise ValueError("injection_metrics needs steps before and after an injection in at least one episode.")
    id_s, ood_s = s[keep & (y == 0)], s[keep & (y == 1)]
    if rng is None:
        row: dict[str, float | int | str] = dict(detection_metrics(id_s, ood_s))
    else:
        row, _ = measure_metrics(id_s, ood_s, rng, n_boot=n_boot, id_clusters=ep[keep & (y == 0)],
                                 ood_clusters=ep[keep & (y == 1)])
    return {**row, "n_episodes": int(injected.size), "n_episodes_dropped": dropped}


def episode_threshold(id_scores: ArrayLike, id_episodes: ArrayLike, alpha: float | None = None
                      ) -> tuple[float, float]:
    """The score above which a step is flagged, calibrated on whole held-out ID episodes, and its false-alarm bound.

    A per-step quantile flags nearly every episode once it has hundreds of steps; the unit that alarms is the
    episode, so the threshold is split conformal on the episodes' maxima, the rule of the guard's episode alarms
    (`guard.conformal`, a later layer): the k-th smallest of the n maxima, k = ceil((n + 1)(1 - alpha)); an ID
    episode exchangeable with them has a step above it with probability at most (n + 1 - k) / (n + 1) <= alpha.
    ``alpha`` None takes the least the n episodes allow, 1 / (n + 1): their largest maximum. Returns (threshold,
    bound).
    """
    s = _as_scores(id_scores, "id_scores")
    ep = np.asarray(id_episodes)
    if ep.shape != s.shape:
        raise ValueError(f"id_scores {s.shape} and id_episodes {ep.shape} need one entry per step each.")
    labels, index = np.unique(ep, return_inverse=True)
    n = labels.size
    alpha = 1.0 / (n + 1) if alpha is None else float(alpha)
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie strictly between 0 and 1, got {alpha!r}.")
    k = math.ceil((n + 1) * (1.0 - alpha) - 1e-9)  # (n + 1)(1 - alpha) is often a whole number up to rounding
    if k > n:
        raise ValueError(f"alpha={alpha:g} needs at least {math.ceil(1.0 / alpha - 1.0 - 1e-9)} held-out ID episodes "
                         f"(n >= 1/alpha - 1), got {n}: the threshold would be infinite.")
    maxima = np.full(n, -np.inf)
    np.maximum.at(maxima, index, s)
    return float(np.partition(maxima, k - 1)[k - 1]), (n + 1 - k) / (n + 1)


def time_matched_auroc(scores: ArrayLike, labels: ArrayLike, steps: ArrayLike, id_scores: ArrayLike,
                       id_steps: ArrayLike) -> float:
    """AUROC of each perturbed step (label 1) against the held-out ID steps at the same step index (ties count 1/2).

    PEDM's pooled AUROC sets late perturbed steps against early ID steps (labels turn 1 at the injection and stay
    1), so a score that grows with time wins without seeing any perturbation; matched by step index, the step index
    itself scores 0.5. The AUROC is over all matched (perturbed, ID) pairs; a perturbed step with no ID step at its
    index is left out (NaN if none has one).
    """
    s, y = _as_scores(scores, "scores"), np.asarray(labels)
    t, id_s, id_t = np.asarray(steps), _as_scores(id_scores, "id_scores"), np.asarray(id_steps)
    if y.shape != s.shape or t.shape != s.shape or id_t.shape != id_s.shape:
        raise ValueError(f"scores {s.shape}, labels {y.shape}, steps {t.shape} and id_scores {id_s.shape}, id_steps "
                         f"{id_t.shape} need one entry per step each.")
    ood_s, ood_t = s[y == 1], t[y == 1].astype(np.int64)
    ranks = rankdata(np.concatenate([id_s, ood_s]), method="dense").astype(np.int64)  # 1..R: one integer key
    width = int(ranks.max()) + 1
    id_t = id_t.astype(np.int64)
    keys = np.sort(id_t * width + ranks[:id_s.size])  # by step, then by score
    ood_key, start = ood_t * width + ranks[id_s.size:], ood_t * width
    before = np.searchsorted(keys, start, "left")
    below = np.searchsorted(keys, ood_key, "left") - before
    tied = np.searchsorted(keys, ood_key, "right") - before - below
    pairs = np.searchsorted(keys, start + width, "left") - before
    if pairs.sum() == 0:
        return float("nan")
    return float((below + 0.5 * tied).sum() / pairs.sum())


def detection_delays(scores: ArrayLike, labels: ArrayLike, episodes: ArrayLike, threshold: float) -> pd.DataFrame:
    """Per injected episode: steps from the injection to the first step scored above ``threshold``.

    Steps are taken in the order given within each episode. ``delay`` is 0 when the first perturbed
    transition is flagged and NaN when none is; ``false_alarm`` says whether a step before the
    injection was flagged already.
    """
    s, y, ep = _per_step(scores, labels, episodes)
    rows = []
    for e in dict.fromkeys(ep.tolist()):
        se, ye = s[ep == e], y[ep == e]
        if not ye.any():
            continue
        start = int(np.argmax(ye == 1))
        flagged = np.flatnonzero(se[start:] > threshold)
        rows.append({"episode": e, "injection_index": start, "delay": float(flagged[0]) if flagged.size else np.nan,
                     "false_alarm": bool((se[:start] > threshold).any())})
    return pd.DataFrame(rows, columns=["episode", "injection_index", "delay", "false_alarm"])


def severity_means(rows: pd.DataFrame, by: tuple[str, ...] = ("severity",),
                   columns: tuple[str, ...] = ("auroc", "aupr_out", "fpr_at_95_tpr")) -> pd.DataFrame:
    """PEDM's summary: each metric averaged over the kinds of each severity (``oodd_runner.py`` l. 164-173).

    ``rows`` has one row per (kind, severity) and whatever else ``by`` names (env, method, detector, ...).
    """
    missing = [c for c in ("kind", *by, *columns) if c not in rows.columns]
    if missing:
        raise ValueError(f"severity_means: rows lack the column(s) {missing}.")
    return rows.groupby(list(by), sort=False)[list(columns)].mean().reset_index()
