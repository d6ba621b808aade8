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

That bound is marginal: for one calibration set the realized false-alarm rate is random,
Beta(n+1-k, k) for continuous scores, and a deployed guard has just one. With ``confidence``
(1 - delta) the rank k is raised to the smallest k with P(Beta(n+1-k, k) > alpha) <= delta
(Vovk 2012, "training-conditional" validity): with probability >= 1 - delta over the calibration
set, this guard's own false-alarm rate is <= alpha. It needs n >= log(delta) / log(1 - alpha)
calibration units (45 for alpha = 0.05, delta = 0.1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.stats import beta as beta_distribution

#: Rounding slack for ceil((n+1)(1-alpha)): (n+1)(1-alpha) is often an integer up to float error.
_EPS = 1e-9


def check_alpha(alpha: float) -> float:
    """alpha is a probability strictly between 0 and 1 (the false-alarm rate the guard may not exceed)."""
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float, np.floating, np.integer)) \
            or not math.isfinite(float(alpha)) or not 0.0 < float(alpha) < 1.0:
        raise ValueError(f"alpha={alpha!r}: the false-alarm rate must lie strictly between 0 and 1, e.g. alpha=0.05.")
    return float(alpha)


def check_confidence(confidence: float | None) -> float | None:
    """None (the marginal guarantee) or a probability strictly between 0 and 1, e.g. 0.9."""
    if confidence is None:
        return None
    if isinstance(confidence, bool) or not isinstance(confidence, (int, float, np.floating, np.integer)) \
            or not math.isfinite(float(confidence)) or not 0.0 < float(confidence) < 1.0:
        raise ValueError(f"confidence={confidence!r}: give the probability (strictly between 0 and 1, e.g. 0.9) that "
                         "the guard's own false-alarm rate stays <= alpha, or None for the marginal guarantee.")
    return float(confidence)


def min_calibration_size(alpha: float, confidence: float | None = None) -> int:
    """The fewest calibration units for a finite threshold: n >= 1/alpha - 1, or with ``confidence``
    n >= log(1 - confidence) / log(1 - alpha) (the largest score as threshold then meets it)."""
    alpha, confidence = check_alpha(alpha), check_confidence(confidence)
    if confidence is None:
        return max(1, math.ceil(1.0 / alpha - 1.0 - _EPS))
    return max(1, math.ceil(math.log(1.0 - confidence) / math.log(1.0 - alpha) - _EPS))


def conformal_rank(n: int, alpha: float, confidence: float | None = None) -> int:
    """The threshold is the k-th smallest of n calibration scores (1-based): k = ceil((n+1)(1-alpha)), or
    with ``confidence`` the smallest k whose realized rate Beta(n+1-k, k) exceeds alpha with probability
    <= 1 - confidence (n + 1 when no k <= n does: too few units)."""
    alpha, confidence = check_alpha(alpha), check_confidence(confidence)
    if confidence is None:
        return math.ceil((n + 1) * (1.0 - alpha) - _EPS)
    ks = np.arange(1, n + 1)
    exceeds = beta_distribution.sf(alpha, n + 1 - ks, ks)  # P(realized false-alarm rate > alpha), falling in k
    ok = np.flatnonzero(exceeds <= 1.0 - confidence + _EPS)
    return int(ks[ok[0]]) if ok.size else n + 1


def check_calibration_size(n: int, alpha: float, unit: str = "calibration states",
                           confidence: float | None = None) -> int:
    """n calibration units give a finite threshold only if n >= min_calibration_size; else one ValueError."""
    need = min_calibration_size(alpha, confidence)
    if n < need:
        if confidence is None:
            raise ValueError(f"alpha={alpha:g} needs at least {need} {unit} (n >= 1/alpha - 1), got {n}: the threshold "
                             f"would be infinite. Pass at least {need} held-out {unit}, or raise alpha to at least "
                             f"{1.0 / (n + 1):.4g} (= 1/(n+1)).")
        raise ValueError(f"alpha={alpha:g} at confidence={confidence:g} needs at least {need} {unit} "
                         f"(n >= log(1 - confidence) / log(1 - alpha)), got {n}. Pass at least {need} held-out {unit}, "
                         "lower the confidence, or use confidence=None for the marginal guarantee.")
    return n


def conformal_threshold(calibration_scores: np.ndarray, alpha: float, unit: str = "calibration states",
                        confidence: float | None = None) -> float:
    """The k-th smallest calibration score (k from ``conformal_rank``); a test score above it is flagged.

    Raises one ValueError naming the fix when the scores are not finite (NaN, +-inf) or too few for alpha.
    ``unit`` names what one score stands for (states, episodes) in that message.
    """
    alpha, confidence = check_alpha(alpha), check_confidence(confidence)
    scores = np.asarray(calibration_scores, dtype=float).reshape(-1)
    if scores.size and not np.isfinite(scores).all():
        raise ValueError(f"the calibration scores hold NaN or inf ({int((~np.isfinite(scores)).sum())} of {scores.size}; "
                         "an inf threshold never alarms, -inf always does); "
                         f"drop those {unit} or fix the score function.")
    n = check_calibration_size(scores.size, alpha, unit, confidence)
    k = conformal_rank(n, alpha, confidence)
    return float(np.partition(scores, k - 1)[k - 1])


def false_alarm_bound(n: int, alpha: float, confidence: float | None = None) -> float:
    """The exact expected false-alarm rate of the threshold for continuous scores: (n + 1 - k) / (n + 1) <= alpha."""
    k = conformal_rank(n, alpha, confidence)
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
