"""Split conformal thresholds and the sequential statistics they are calibrated on (pure numpy).

The guarantee (Vovk et al. 2005; Angelopoulos & Bates 2021, "A gentle introduction"): let
s_1..s_n be the calibration scores and s_{n+1} a test score, and assume the n+1 are
**exchangeable** (e.g. i.i.d. draws of the same kind of unit). With k = ceil((n+1)(1-alpha)) and
q the k-th smallest calibration score,

    P(s_{n+1} > q) <= alpha            (and >= alpha - 1/(n+1) when scores have no ties).

The probability is over the calibration set and the test unit together. k <= n needs
n >= 1/alpha - 1; with fewer units q would be +infinity (nothing could ever be flagged).

For a sequence of states the unit is a whole episode: a sequential statistic (the mean of the
last w scores, or a CUSUM) is computed along the episode, and its maximum over the episode is
one calibration score. Then "this ID episode raises at least one alarm" has probability at
most alpha, for episodes exchangeable with the calibration episodes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

#: Rounding slack for ceil((n+1)(1-alpha)): (n+1)(1-alpha) is often an integer up to float error.
_EPS = 1e-9


def check_alpha(alpha: float) -> float:
    """alpha is a probability strictly between 0 and 1 (the false-alarm rate the guard may not exceed)."""
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float, np.floating, np.integer)) \
            or not math.isfinite(float(alpha)) or not 0.0 < float(alpha) < 1.0:
        raise ValueError(f"alpha={alpha!r}: the false-alarm rate must lie strictly between 0 and 1, e.g. alpha=0.05.")
    return float(alpha)


def min_calibration_size(alpha: float) -> int:
    """The fewest calibration units for which the conformal threshold is finite: n >= 1/alpha - 1."""
    alpha = check_alpha(alpha)
    return max(1, math.ceil(1.0 / alpha - 1.0 - _EPS))


def conformal_rank(n: int, alpha: float) -> int:
    """k = ceil((n+1)(1-alpha)): the threshold is the k-th smallest of n calibration scores (1-based)."""
    return math.ceil((n + 1) * (1.0 - check_alpha(alpha)) - _EPS)


def check_calibration_size(n: int, alpha: float, unit: str = "calibration states") -> int:
    """n calibration units give a finite threshold for alpha only if n >= 1/alpha - 1; else one ValueError."""
    need = min_calibration_size(alpha)
    if n < need:
        raise ValueError(f"alpha={alpha:g} needs at least {need} {unit} (n >= 1/alpha - 1), got {n}: the threshold "
                         f"would be infinite. Pass at least {need} held-out {unit}, or raise alpha to at least "
                         f"{1.0 / (n + 1):.4g} (= 1/(n+1)).")
    return n


def conformal_threshold(calibration_scores: np.ndarray, alpha: float, unit: str = "calibration states") -> float:
    """The k-th smallest calibration score, k = ceil((n+1)(1-alpha)); a test score above it is flagged.

    Raises one ValueError naming the fix when the scores are not finite or too few for alpha.
    ``unit`` names what one score stands for (states, episodes) in that message.
    """
    alpha = check_alpha(alpha)
    scores = np.asarray(calibration_scores, dtype=float).reshape(-1)
    if scores.size and np.isnan(scores).any():
        raise ValueError(f"the calibration scores hold NaN ({int(np.isnan(scores).sum())} of {scores.size}); "
                         f"drop those {unit} or fix the score function.")
    n = check_calibration_size(scores.size, alpha, unit)
    k = conformal_rank(n, alpha)
    return float(np.partition(scores, k - 1)[k - 1])


def false_alarm_bound(n: int, alpha: float) -> float:
    """The exact expected false-alarm rate of the threshold for continuous scores: (n + 1 - k) / (n + 1) <= alpha."""
    k = conformal_rank(n, alpha)
    return (n + 1 - k) / (n + 1)


# ------------------------------------------------------------------- sequential calibration inputs


def episode_maximum(path: np.ndarray) -> float:
    """The calibration score of one episode: the largest value its statistic took (-inf if never defined)."""
    p = np.asarray(path, dtype=float)
    return float(p.max()) if p.size else -np.inf


def check_window(window: int) -> int:
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise ValueError(f"window={window!r}: the sliding window needs a whole number of steps >= 1, e.g. window=10.")
    return int(window)


def check_drift(drift: float) -> float:
    if isinstance(drift, bool) or not isinstance(drift, (int, float, np.floating, np.integer)) \
            or not math.isfinite(float(drift)):
        raise ValueError(f"drift={drift!r}: the CUSUM drift must be a finite number in score units, e.g. a high "
                         "quantile of ID scores (Cusum.from_reference).")
    return float(drift)


def check_episodes(episodes: Sequence[np.ndarray], what: str = "calibration episodes") -> list[np.ndarray]:
    """A list of 1-D per-step score arrays, each non-empty and finite."""
    if isinstance(episodes, np.ndarray) and episodes.ndim == 1:
        raise ValueError(f"{what}: got one flat array; pass a list with one array of per-step scores (or states) "
                         "per whole episode.")
    out = [np.asarray(e, dtype=float).reshape(-1) for e in episodes]
    for i, e in enumerate(out):
        if e.size == 0:
            raise ValueError(f"{what}: episode {i} is empty; every episode needs at least one step.")
        if not np.all(np.isfinite(e)):
            raise ValueError(f"{what}: episode {i} has NaN/inf scores; drop that episode or fix the score function.")
    return out
