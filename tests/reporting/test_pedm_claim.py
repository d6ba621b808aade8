"""Claim 7 (pre-registered 2026-12-05): the agents' own uncertainty against PEDM, claim 5's rule on paired seeds."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from paper_lib.reporting.claims import FAILS, HOLDS, ClaimDesign, base_verdict
from paper_lib.reporting.pedm_claim import NOT_SCORED, pedm_rows, pedm_versus

SEEDS = range(5)


def _runs(offsets: dict[tuple[str, str], list[float]], pedm: list[float], env: str = "HalfCheetah-v5") -> pd.DataFrame:
    """Per-run AUROCs: PEDM's per seed, and each (method, measure) cell at PEDM's plus its per-seed offset."""
    rows = []
    for (method, measure), deltas in offsets.items():
        for seed, (p, d) in enumerate(zip(pedm, deltas)):
            rows.append({"env": env, "method": method, "seed": seed, "measure": measure, "auroc": p + d})
            rows.append({"env": env, "method": method, "seed": seed, "measure": "pedm", "auroc": p})
    return pd.DataFrame(rows).drop_duplicates(["env", "method", "seed", "measure"])


PEDM = [0.70, 0.75, 0.72, 0.68, 0.74]


def test_differences_are_paired_per_seed_with_t_intervals_and_simultaneous_ones():
    runs = _runs({("masksembles", "value_std"): [0.10, 0.12, 0.11, 0.09, 0.10],
                  ("masksembles", "policy_std"): [-0.01, 0.02, 0.0, -0.02, 0.01]}, PEDM)
    versus = pedm_versus(runs)
    value = versus.set_index("measure").loc["value_std"]
    d = np.array([0.10, 0.12, 0.11, 0.09, 0.10])
    half = 2.7764451051977987 * d.std(ddof=1) / np.sqrt(5)  # Student's t, 4 degrees of freedom, 95%
    assert value.difference == pytest.approx(d.mean())
    assert (value.ci_low, value.ci_high) == pytest.approx((d.mean() - half, d.mean() + half))
    assert value.family_size == 2 and value.family_ci_low < value.ci_low  # Bonferroni over the env's 2 cells
    assert value.n_seeds == 5 and value.detector == "pedm"


def test_holds_when_some_cell_clears_pedm_simultaneously_and_fails_when_every_cell_is_below():
    above = _runs({("masksembles", "value_std"): [0.10, 0.12, 0.11, 0.09, 0.10],
                   ("ensemble", "policy_std"): [-0.01, 0.02, 0.0, -0.02, 0.01]}, PEDM)
    below = _runs({("masksembles", "value_std"): [-0.10, -0.12, -0.11, -0.09, -0.10],
                   ("ensemble", "policy_std"): [-0.05, -0.06, -0.04, -0.05, -0.07]}, PEDM)
    mixed = _runs({("masksembles", "value_std"): [-0.10, -0.12, -0.11, -0.09, -0.10],
                   ("ensemble", "policy_std"): [-0.05, 0.06, -0.04, 0.05, -0.07]}, PEDM)
    assert [r["verdict"] for r in pedm_rows(above)] == [HOLDS]
    assert [r["verdict"] for r in pedm_rows(below)] == [FAILS]
    assert base_verdict(pedm_rows(mixed)[0]["verdict"]) == "inconclusive"
    assert "vs pedm" in pedm_rows(above)[0]["evidence"]


def test_fewer_seeds_than_planned_are_provisional_and_one_seed_never_decides():
    runs = _runs({("masksembles", "value_std"): [0.10, 0.12, 0.11]}, PEDM[:3])
    design = ClaimDesign(planned_seeds={"MuJoCo": 5})
    assert pedm_rows(runs, design)[0]["verdict"] == "holds, provisional (3 of 5 seeds)"
    one = _runs({("masksembles", "value_std"): [0.30]}, PEDM[:1])
    assert pedm_rows(one)[0]["verdict"] == "inconclusive (1 seed)"
    assert "+0.30 [no interval: 1 seed], simultaneous over 1 [no interval: 1 seed]" in pedm_rows(one)[0]["evidence"]


def test_no_scores_yet_is_a_row_per_mujoco_env_that_says_so_and_a_duplicate_run_is_refused():
    assert pedm_rows(None) == pedm_rows(pd.DataFrame()) == []
    rows = pedm_rows(None, envs=["HalfCheetah-v5", "SeaquestNoFrameskip-v4", "Ant-v5"])  # per MuJoCo env, as registered
    assert [(r["env"], r["verdict"]) for r in rows] == [("HalfCheetah-v5", NOT_SCORED), ("Ant-v5", NOT_SCORED)]
    runs = _runs({("masksembles", "value_std"): [0.1, 0.1]}, PEDM[:2])
    with pytest.raises(ValueError, match="HalfCheetah-v5 masksembles seed 0 value_std more than once"):
        pedm_versus(pd.concat([runs, runs.iloc[:1]]))
    with pytest.raises(ValueError, match=r"missing: rebuild the PEDM-protocol table"):
        pedm_versus(runs.drop(columns="auroc"))


def test_the_committed_pedm_run_is_read_as_pedm_reports_it_and_a_baseline_alone_decides_nothing():
    """The committed `pedm` stage output (HalfCheetah baseline seed 0): each scorer's AUROC is the mean of its two
    per-severity means; a baseline run has no member measure, so the claim still reads not testable, saying why."""
    from pathlib import Path

    from paper_lib.pipeline.config import load_run_config
    from paper_lib.pipeline.pedm_stage import run_aurocs

    root = Path(__file__).resolve().parents[2]
    cfg = load_run_config(root / "params.yaml")
    runs = run_aurocs(cfg, [("HalfCheetah-v5", "baseline", 0), ("HalfCheetah-v5", "baseline", 99)])
    metrics = pd.read_csv(cfg.layout.pedm_dir("HalfCheetah-v5", "baseline", 0) / "metrics.csv")
    pedm_means = metrics[(metrics.scorer == "pedm") & (metrics.kind == "mean")].auroc
    assert len(pedm_means) == 2 and set(runs.measure) == {"pedm", "episode_mean", "window_forest"}
    assert runs.set_index("measure").auroc["pedm"] == pytest.approx(pedm_means.mean())
    (row,) = pedm_rows(runs)
    assert row["verdict"] == NOT_SCORED and row["evidence"].startswith("1 run(s) have PEDM-protocol scores, none of")
