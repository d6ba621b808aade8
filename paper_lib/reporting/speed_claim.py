"""The paper's speed claim as a verdict: "Masksembles infers faster than MC Dropout and trains comparably".

Section 4 of the paper says Masksembles "performs comparably to MC Dropout" in training and "outperforms the latter
in terms of inference speed because Masksembles can generate output distributions in a single forward-pass".
Issue 70 asks for a verdict with the benchmark's run-to-run spread, under the other claims' rule shape; the rule
was registered (params.yaml `preregistration.speed`, docs/preregistration.md) on 2026-12-05, before any benchmark
run that records its repetitions.

It reads the benchmark's every repetition (`bench_timings.csv`). Per env, three parts, each on Masksembles /
MC Dropout paired by repetition (repetition i of both was timed in the same interleaved round, or PPO iteration),
a Student's t interval of the mean log ratio, exponentiated:
- "infers faster", for each registered inference timing (time ratio): holds when the interval lies below 1,
  does not hold when it lies at or above 1;
- "trains comparably" (training-rate ratio, non-inferiority as the reward claim): holds when the interval lies at
  or above 1 - margin, does not hold when it lies below it.
The claim holds when every part holds (each part's own 95% interval: all must); it does not hold when some part does
not, judged on intervals simultaneous over the parts (Bonferroni: one of m chances, as the AUROC-order claim);
inconclusive otherwise. Fewer paired repetitions than registered: not testable.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import t as student_t

from paper_lib.reporting.claims import FAILS, HOLDS

FAST, SLOW = "masksembles", "mc_dropout"
NO_BENCHMARK = "not testable (no benchmark with repetitions committed)"
TIMING_COLUMNS = ("env_id", "method", "measurement", "repetition", "value")


def read_timings(path: str | Path) -> pd.DataFrame | None:
    """The benchmark's repetitions, or None where none is committed (the claim then reads `NO_BENCHMARK`)."""
    path = Path(path)
    if not path.is_file():
        return None
    table = pd.read_csv(path)
    missing = sorted(set(TIMING_COLUMNS) - set(table.columns))
    if missing:
        raise ValueError(f"{path} lacks columns {missing}: it is not the benchmark's bench_timings.csv")
    return table


def paired_log_ratios(timings: pd.DataFrame, env: str, measurement: str) -> np.ndarray:
    """log(Masksembles / MC Dropout) of each repetition both have, in repetition order."""
    rows = timings[(timings["env_id"] == env) & (timings["measurement"] == measurement)]
    a = rows[rows["method"] == FAST].set_index("repetition")["value"]
    b = rows[rows["method"] == SLOW].set_index("repetition")["value"]
    both = a.index.intersection(b.index).sort_values()
    return np.log(a[both].to_numpy(float) / b[both].to_numpy(float))


def ratio_interval(logs: np.ndarray, level: float) -> tuple[float, float, float]:
    """(geometric-mean ratio, low, high): the t interval of the mean log ratio, exponentiated (NaN below 2)."""
    if logs.size < 2:
        return float(np.exp(logs.mean())) if logs.size else np.nan, np.nan, np.nan
    half = student_t.ppf(0.5 + level / 2, logs.size - 1) * logs.std(ddof=1) / np.sqrt(logs.size)
    mean = logs.mean()
    return float(np.exp(mean)), float(np.exp(mean - half)), float(np.exp(mean + half))


def part_verdict(logs: np.ndarray, bound: float, faster: bool, level: float, family_level: float
                 ) -> tuple[str, str]:
    """One part's verdict and its evidence. `faster`: success is a time ratio below `bound`; else a rate ratio at
    or above it. Holds on the part's own interval, does not hold on its simultaneous one."""
    ratio, low, high = ratio_interval(logs, level)
    _, f_low, f_high = ratio_interval(logs, family_level)
    if faster:
        verdict = HOLDS if high < bound else FAILS if f_low >= bound else "inconclusive"
    else:
        verdict = HOLDS if low >= bound else FAILS if f_high < bound else "inconclusive"
    return verdict, (f"{ratio:.3f} [{low:.3f}, {high:.3f}], simultaneous [{f_low:.3f}, {f_high:.3f}] "
                     f"vs {bound:g} ({verdict})")


def speed_claim(timings: pd.DataFrame | None, inference: tuple[str, ...], training: str, margin: float,
                min_repetitions: int, level: float) -> list[tuple[str, str, str]]:
    """(env, verdict, evidence) per benchmark env; one row for "all" while no benchmark with repetitions exists."""
    if timings is None or timings.empty:
        return [("all", NO_BENCHMARK, "the benchmark's repetitions (bench_timings.csv) are not committed yet: "
                                      "`make bench` writes them")]
    parts = [(m, True, 1.0) for m in inference] + [(training, False, 1.0 - margin)]
    family = 1.0 - (1.0 - level) / len(parts)
    rows = []
    for env in pd.unique(timings["env_id"]):
        logs = {name: paired_log_ratios(timings, env, name) for name, _, _ in parts}
        short = {name: v.size for name, v in logs.items() if v.size < min_repetitions}
        if short:
            rows.append((env, f"not testable ({min(short.values())} paired repetitions; needs at least "
                              f"{min_repetitions})", "too few paired repetitions of Masksembles and MC Dropout: "
                         + ", ".join(f"{name} {n}" for name, n in short.items())))
            continue
        verdicts, evidence = [], []
        for name, faster, bound in parts:
            verdict, text = part_verdict(logs[name], bound, faster, level, family)
            verdicts.append(verdict)
            kind = "time" if faster else "rate"
            evidence.append(f"{name} Masksembles / MC Dropout {kind} {text}")
        n = min(v.size for v in logs.values())
        verdict = (HOLDS if all(v == HOLDS for v in verdicts) else FAILS if FAILS in verdicts
                   else f"inconclusive ({n} repetitions)")
        rows.append((env, verdict, "; ".join(evidence) + f"; {n} paired repetitions, {level:.0%} intervals"))
    return rows
