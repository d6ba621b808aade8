"""The speed claim's registered rule on constructed benchmark repetitions: holds, does not hold, inconclusive,
not testable; and its row in the claims table."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from paper_lib.reporting.claims import CLAIMS, FAILS, HOLDS, ClaimDesign, speed_rows
from paper_lib.reporting.speed_claim import NO_BENCHMARK, ratio_interval, read_timings

INFERENCE = ("act_uncertainty_b1", "uncertainty_b4096")
#: Repetition-to-repetition wobble of a log ratio: the same in every table, so only the ratios differ.
WOBBLE = np.array([0.02, -0.01, 0.015, -0.02, 0.0, 0.01, -0.015])


def _timings(infer: float, train: float, reps: int = 7, wobble: float = 1.0, env: str = "HalfCheetah-v5"
             ) -> pd.DataFrame:
    """Masksembles / MC Dropout time ratio `infer` (both inference timings) and rate ratio `train`, per repetition."""
    rows = []
    for i in range(reps):
        e = np.exp(wobble * WOBBLE[i % WOBBLE.size])
        for name in INFERENCE:
            rows += [(env, "mc_dropout", name, i, 2.0, "ms"), (env, "masksembles", name, i, 2.0 * infer * e, "ms")]
        rows += [(env, "mc_dropout", "train_steps_per_s", i, 500.0, "steps/s"),
                 (env, "masksembles", "train_steps_per_s", i, 500.0 * train * e, "steps/s"),
                 (env, "baseline", "train_steps_per_s", i, 600.0, "steps/s")]
    return pd.DataFrame(rows, columns=["env_id", "method", "measurement", "repetition", "value", "unit"])


def _verdict(timings: pd.DataFrame | None) -> str:
    rows = speed_rows(timings)
    assert {r["claim"] for r in rows} == {CLAIMS["speed"]}
    return rows[0]["verdict"]


def test_faster_inference_and_training_within_the_margin_holds():
    assert _verdict(_timings(infer=0.7, train=0.95)) == HOLDS  # 5% slower training: inside the 10% margin
    assert _verdict(_timings(infer=0.7, train=1.2)) == HOLDS  # faster training is comparable too (non-inferiority)


def test_slower_inference_or_training_beyond_the_margin_does_not_hold():
    assert _verdict(_timings(infer=1.05, train=1.0)) == FAILS  # every repetition at or above 1
    assert _verdict(_timings(infer=0.5, train=0.8)) == FAILS  # training 20% slower: past the margin
    rows = speed_rows(_timings(infer=0.5, train=0.8))
    assert "train_steps_per_s Masksembles / MC Dropout rate 0.800" in rows[0]["evidence"]


def test_intervals_that_straddle_the_bound_are_inconclusive():
    """A ratio of 0.99 with a wobble of several percent, or training at the margin itself: no decision."""
    assert _verdict(_timings(infer=0.99, train=1.0, wobble=3.0)) == "inconclusive (7 repetitions)"
    assert _verdict(_timings(infer=0.7, train=0.9, wobble=3.0)) == "inconclusive (7 repetitions)"


def test_failure_needs_the_simultaneous_interval():
    """One part's own 95% interval above 1 is not enough to fail when its interval over the three parts reaches
    below 1: three chances to fail by luck."""
    logs = np.log(1.02) + 1.2 * WOBBLE[:6]
    _, low, _ = ratio_interval(logs, 0.95)
    _, family_low, _ = ratio_interval(logs, 1 - 0.05 / 3)
    assert low > 1.0 > family_low  # the case this test is about
    timings = _timings(infer=0.7, train=1.0, reps=6)
    target = (timings.method == "masksembles") & (timings.measurement == "uncertainty_b4096")
    timings.loc[target, "value"] = 2.0 * np.exp(logs)
    assert _verdict(timings) == "inconclusive (6 repetitions)"


def test_too_few_repetitions_or_no_benchmark_is_not_testable(tmp_path):
    assert _verdict(_timings(infer=0.5, train=1.0, reps=4)) == "not testable (4 paired repetitions; needs at least 5)"
    assert _verdict(None) == NO_BENCHMARK
    assert read_timings(tmp_path / "bench_timings.csv") is None
    _timings(0.7, 1.0).to_csv(tmp_path / "bench_timings.csv", index=False)
    assert _verdict(read_timings(tmp_path / "bench_timings.csv")) == HOLDS
    pd.DataFrame({"env_id": ["x"]}).to_csv(tmp_path / "other.csv", index=False)
    with pytest.raises(ValueError, match="lacks columns"):
        read_timings(tmp_path / "other.csv")


def test_one_row_per_benchmark_env_and_the_registered_design():
    both = pd.concat([_timings(0.7, 1.0), _timings(1.1, 1.0, env="SeaquestNoFrameskip-v4")])
    rows = speed_rows(both)
    assert [(r["env"], r["verdict"]) for r in rows] == [("HalfCheetah-v5", HOLDS), ("SeaquestNoFrameskip-v4", FAILS)]
    strict = ClaimDesign(speed_margin=0.02)
    assert speed_rows(_timings(0.7, 0.95), strict)[0]["verdict"] == FAILS  # the margin is the design's


def test_the_registered_speed_rule_is_params_yaml_s():
    from paper_lib.pipeline.config import read_params
    from paper_lib.reporting.preregistration import Preregistration

    prereg = Preregistration.from_params(read_params())
    design = ClaimDesign.from_preregistration(prereg, pd.DataFrame(columns=["claim", "env", "seeds_needed", "note"]))
    default = ClaimDesign()
    assert (design.speed_inference, design.speed_training, design.speed_margin, design.speed_min_repetitions) == \
        (default.speed_inference, default.speed_training, default.speed_margin, default.speed_min_repetitions)
    assert prereg.speed["registered"] == "2026-12-05" and prereg.speed["margin"] == prereg.reward_margin
    assert prereg.speed["timings"] == "results/bench/bench_timings.csv"
