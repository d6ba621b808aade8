"""OOD detection metrics.

Convention used everywhere in this module: **OOD states are the positive class**
(label 1), ID states the negative class (label 0), and the uncertainty is the score
(higher = more likely OOD). "FPR@95" therefore means: the fraction of ID states
flagged as OOD when the threshold is set so that 95% of OOD states are flagged.
Libraries that take ID as positive report a different number under the same name.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
from scipy.stats import rankdata
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
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}.")
    if int(n_boot) != n_boot or n_boot < 1:
        raise ValueError(f"n_boot must be a positive integer, got {n_boot!r}.")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie strictly between 0 and 1 (e.g. 0.95), got {level!r}.")
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


def metrics_table(
    scores: Mapping[str, tuple[ArrayLike, ArrayLike]],
    rng: np.random.Generator,
    n_boot: int = 1000,
    level: float = 0.95,
) -> pd.DataFrame:
    """One row per uncertainty measure: all detection metrics plus the AUROC bootstrap CI.

    ``scores`` maps a measure name (e.g. "value_uncertainty") to its (ID, OOD) score
    arrays. Rows keep the mapping's order; the CI columns are auroc_ci_low/high.
    """
    if not isinstance(scores, Mapping) or len(scores) == 0:
        raise ValueError("scores must be a non-empty dict {measure name: (id_scores, ood_scores)}.")
    rows = []
    for measure, pair in scores.items():
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise ValueError(f"scores[{measure!r}] must be a pair (id_scores, ood_scores), got {type(pair).__name__}.")
        id_s, ood_s = pair
        try:
            row = detection_metrics(id_s, ood_s)
            low, high = bootstrap_auroc_ci(id_s, ood_s, rng, n_boot=n_boot, level=level)
        except ValueError as err:
            raise ValueError(f"scores[{measure!r}]: {err}") from None
        rows.append({"measure": measure, **row, "auroc_ci_low": low, "auroc_ci_high": high})
    return pd.DataFrame(rows)
