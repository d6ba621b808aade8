"""Verdicts that hold up (issue 36): one rule shape for every claim, like-with-like comparison with the paper
(the intervals over seeds they read, at least Student's t: tests/scoring/test_statistics.py)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from paper_lib.reporting.claims import FAILS, HOLDS, MIXED, auroc_claim, combine, decide, reward_claim

ROOT = Path(__file__).resolve().parents[2]


def _reward_row(low: float, high: float, baseline: float = 1000.0, n_seeds: int = 3) -> dict:
    return {"env": "HalfCheetah-v5", "method": "masksembles", "inference": "combined", "sampled difference": (low + high) / 2,
            "sampled ci_low": low, "sampled ci_high": high, "sampled baseline": baseline, "deterministic difference": 0.0,
            "deterministic ci_low": -1.0, "deterministic ci_high": 1.0, "n_seeds": n_seeds}


@pytest.mark.parametrize(("low", "high", "n_seeds", "verdict"), [
    (-500, 50, 3, "inconclusive (3 seeds)"),  # a possible loss of half the reward is not "keeps" it
    (-50, 200, 3, HOLDS),                     # every loss the interval allows is within the 10% margin
    (-400, -150, 3, FAILS),                   # the whole interval is a loss beyond the margin
    (-400, -50, 3, "inconclusive (3 seeds)"),
    (10, 50, 1, "inconclusive (1 seed)"),     # one run's episodes say nothing of the method
])
def test_reward_claim_is_non_inferiority_with_a_stated_margin(low, high, n_seeds, verdict):
    [row] = reward_claim(pd.DataFrame([_reward_row(low, high, n_seeds=n_seeds)]))
    assert row["verdict"] == verdict
    assert "margin -100 (10% of the baseline's 1000)" in row["evidence"] and f"{n_seeds} seed(s)" in row["evidence"]


def test_one_rule_shape_for_both_directions():
    assert decide(0.01, 0.2, 0.0, 3) == HOLDS and decide(-0.2, -0.01, 0.0, 3) == FAILS
    assert decide(-0.2, 0.2, 0.0, 3) == "inconclusive (3 seeds)"
    assert combine([HOLDS, HOLDS], 3) == HOLDS and combine([FAILS, FAILS], 3) == FAILS
    assert combine([HOLDS, FAILS], 3) == MIXED and combine([HOLDS, "inconclusive (3 seeds)"], 3) == "inconclusive (3 seeds)"


def _pairwise(lows: list[float], highs: list[float], n_seeds: int = 3, widen: float = 0.0) -> pd.DataFrame:
    """The four pairs per measure; their simultaneous intervals `widen` wider on each side."""
    pairs = [("masksembles", "mc_dropout"), ("masksembles", "mc_dropconnect"), ("ensemble", "mc_dropout"),
             ("ensemble", "mc_dropconnect")]
    rows = [{"env": "Swimmer-v5", "ood_set": "perturbed", "measure": measure, "method": a, "versus": b,
             "difference": (lo + hi) / 2, "ci_low": lo, "ci_high": hi, "family_size": 4, "family_ci_low": lo - widen,
             "family_ci_high": hi + widen, "n_seeds": n_seeds}
            for measure in ("value_std", "policy_std") for (a, b), lo, hi in zip(pairs, lows, highs)]
    return pd.DataFrame(rows)


def test_auroc_order_needs_every_pair_ahead_and_fails_on_one_pair_behind():
    assert auroc_claim(_pairwise([0.1] * 4, [0.3] * 4))[0]["verdict"] == HOLDS
    assert auroc_claim(_pairwise([0.1] * 4, [0.3] * 4, widen=0.5))[0]["verdict"] == HOLDS  # all four: no correction
    assert auroc_claim(_pairwise([0.1, 0.1, -0.1, 0.1], [0.3] * 4))[0]["verdict"] == "inconclusive (3 seeds)"
    assert auroc_claim(_pairwise([0.1, 0.1, -0.3, 0.1], [0.3, 0.3, -0.1, 0.3]))[0]["verdict"] == FAILS
    # one pair of four behind at 95%, but not once the four chances are accounted for: not a failure
    assert auroc_claim(_pairwise([0.1, 0.1, -0.3, 0.1], [0.3, 0.3, -0.1, 0.3], widen=0.15))[0]["verdict"] \
        == "inconclusive (3 seeds)"
    assert auroc_claim(_pairwise([0.1] * 4, [0.3] * 4, n_seeds=1))[0]["verdict"] == "inconclusive (1 seed)"


def test_paper_comparison_subtracts_the_paper_from_our_sampled_reward():
    """The committed paper-vs-us table compares like with like: the paper's Table 1 samples its actions."""
    tables = ROOT / "results" / "paper" / "tables"
    ours = pd.read_csv(tables / "rewards_long.csv")
    compared = pd.read_csv(tables / "paper_vs_us_rewards.csv")
    sampled = ours[~ours.deterministic].assign(
        inference=lambda d: d.inference.where(d.method != "baseline", "single")).set_index(["method", "inference", "env"])
    for row in compared.itertuples():
        assert row.ours == pytest.approx(sampled.loc[(row.method, row.inference, row.env), "mean"])
        assert row.difference == pytest.approx(row.ours - row.paper)
