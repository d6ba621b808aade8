"""How many training seeds a verdict needs: the power of the claims' rules, from the spread of the seeds we have.

Every interval over seeds is at least Student's t over the per-seed values (`statistics.t_interval`), and with few
seeds that floor is what decides. So the chance that a rule decides at n seeds is the chance that a t interval
clears a bound, which the noncentral t distribution gives exactly (scipy's `nct`, what statsmodels' power functions
compute): for a true mean difference `effect`, a seed-to-seed std `sd` and a bound b, the statistic
(mean - b) / (s / sqrt(n)) follows nct(n - 1, (effect - b) sqrt(n) / sd). A claim of several cells combines the
cells' chances as its rule does (all of k, any of k), treating cells as independent: an approximation, stated in
docs/preregistration.md. `effect` and `sd` come from the committed seeds (scripts/power_analysis.py), so they are
themselves estimates from 3 seeds: the counts are "about", and the pre-registration fixes them once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.stats import nct
from scipy.stats import t as student_t

#: The most seeds a count is searched up to; beyond it a count reads "over MAX_SEEDS".
MAX_SEEDS = 200


def clear_probabilities(effect: float, sd: float, n: int, bound: float, level_above: float = 0.95,
                        level_below: float = 0.95) -> tuple[float, float]:
    """(P(the interval lies at or above `bound`), P(it lies below `bound`)) for n seeds.

    `level_above` / `level_below` are the two-sided levels of the intervals each side reads (0.95, or a
    simultaneous level 1 - 0.05 / m where one of m cells decides that side).
    """
    if n < 2:
        return 0.0, 0.0
    if not (np.isfinite(effect) and np.isfinite(sd)) or sd < 0:
        raise ValueError(f"effect and sd must be finite numbers, sd >= 0; got effect={effect!r}, sd={sd!r}.")
    df = n - 1
    crit_above = student_t.ppf(0.5 + level_above / 2.0, df)
    crit_below = student_t.ppf(0.5 + level_below / 2.0, df)
    if sd == 0:  # every seed the same: the interval is a point
        return float(effect >= bound), float(effect < bound)
    nc = (effect - bound) * np.sqrt(n) / sd
    return _tail(nct.sf(crit_above, df, nc), far=nc < 0), _tail(nct.cdf(-crit_below, df, nc), far=nc > 0)


def _tail(probability: float, far: bool) -> float:
    """scipy's nct returns NaN where a tail underflows (|nc| in the tens): 0 on the far side, 1 on the near."""
    if np.isnan(probability):
        return 0.0 if far else 1.0
    return float(probability)


def all_of(probabilities: Sequence[float]) -> float:
    """The chance that every one of independent events happens."""
    return float(np.prod(probabilities))


def any_of(probabilities: Sequence[float]) -> float:
    """The chance that at least one of independent events happens."""
    return float(1.0 - np.prod(1.0 - np.asarray(probabilities, dtype=float)))


def at_least(probabilities: Sequence[float], k: int) -> float:
    """The chance that at least k of independent events happen (the Poisson binomial's upper tail)."""
    dist = np.array([1.0])
    for p in probabilities:
        dist = np.convolve(dist, [1.0 - p, p])
    return float(dist[k:].sum())


def seeds_needed(decide_probability: Callable[[int], float], power: float = 0.8,
                 max_seeds: int = MAX_SEEDS) -> int | None:
    """The fewest seeds n >= 2 at which `decide_probability(n)` (holds or does not hold) reaches `power`;
    None when not within `max_seeds`."""
    if not 0.0 < power < 1.0:
        raise ValueError(f"power must lie strictly between 0 and 1 (e.g. 0.8), got {power!r}.")
    for n in range(2, int(max_seeds) + 1):
        if decide_probability(n) >= power:
            return n
    return None
