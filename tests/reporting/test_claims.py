"""The verdict rules of the paper's claims, on small tables whose answers are known by hand.

One rule shape for every claim that rests on an interval (tests/reporting/test_verdicts.py checks it case by case):
holds when the interval excludes failure, does not hold when it excludes success, inconclusive otherwise.
"""

from __future__ import annotations

import pandas as pd
import pytest

import numpy as np

from paper_lib.reporting.claims import (AUROC_ORDER_PAIRS, CLAIMS, FAILS, HOLDS, MIXED, UNTESTED, ClaimDesign,
                                        auroc_claim, base_verdict, detector_claim, js_claim, levitation_claim,
                                        paper_claims, reward_claim)
from paper_lib.reporting.pedm_claim import NOT_SCORED as PEDM_NOT_SCORED
from paper_lib.reporting.speed_claim import NO_BENCHMARK


def _vs_baseline(ci_low: float, ci_high: float, baseline: float = 100.0, n_seeds: int = 3) -> pd.DataFrame:
    return pd.DataFrame([{"env": "Swimmer-v5", "method": "masksembles", "inference": "combined",
                          "sampled difference": (ci_low + ci_high) / 2, "sampled ci_low": ci_low,
                          "sampled ci_high": ci_high, "sampled baseline": baseline, "deterministic difference": 5.0,
                          "deterministic ci_low": 1.0, "deterministic ci_high": 9.0, "n_seeds": n_seeds}])


def _pairwise(intervals: dict[str, tuple[float, float]], n_seeds: int = 3) -> pd.DataFrame:
    """Every AUROC-order pair with the same interval per measure."""
    return pd.DataFrame([{"env": "Swimmer-v5", "ood_set": "perturbed", "measure": measure, "method": a, "versus": b,
                          "difference": (lo + hi) / 2, "ci_low": lo, "ci_high": hi, "family_size": 4,
                          "family_ci_low": lo, "family_ci_high": hi, "n_seeds": n_seeds}
                         for measure, (lo, hi) in intervals.items() for a, b in AUROC_ORDER_PAIRS])


def _metrics(aurocs: dict[tuple[str, str], float], envs: tuple[str, ...] = ("Swimmer-v5", "Walker2d-v5"),
             conditions: int = 50) -> pd.DataFrame:
    """The same cells in each env, shifted a little per env, so the JS claim has 2 x methods (env, method) cells."""
    return pd.DataFrame([{"env": env, "ood_set": "perturbed", "method": m, "measure": s, "auroc": a + 0.01 * i,
                          "n_seeds": 3, "n_ood_clusters": float(conditions)}
                         for i, env in enumerate(envs) for (m, s), a in aurocs.items()])


def _versus(ci: list[tuple[float, float]], n_seeds: int = 3, family: list[tuple[float, float]] | None = None
            ) -> pd.DataFrame:
    """Detector differences; `family`: the simultaneous intervals (default: the same as the cells' own)."""
    family = ci if family is None else family
    return pd.DataFrame([{"env": "Swimmer-v5", "ood_set": "perturbed", "method": "masksembles", "measure": f"m{i}",
                          "difference": (lo + hi) / 2, "ci_low": lo, "ci_high": hi, "family_size": len(ci),
                          "family_ci_low": f_lo, "family_ci_high": f_hi, "detector": "knn_obs", "n_seeds": n_seeds}
                         for i, ((lo, hi), (f_lo, f_hi)) in enumerate(zip(ci, family))])


def _spawn(cells: dict[str, tuple[float, float]], spread: float = 0.01) -> pd.DataFrame:
    """Ant spawn rows, 3 seeds per method, around (spawn ratio, airborne AUROC)."""
    return pd.DataFrame([{"env": "Ant-v5", "method": m, "seed": s, "value_std_spawn_ratio": r * np.exp(spread * (s - 1)),
                          "value_std_airborne_auroc": a + spread * (s - 1)}
                         for m, (r, a) in cells.items() for s in range(3)])


def _verdicts(table: pd.DataFrame) -> dict[str, str]:
    return {key: table[table.claim == text].verdict.tolist()[0] for key, text in CLAIMS.items()}


JS = {("masksembles", "policy_std"): 0.7, ("ensemble", "policy_std"): 0.5, ("mc_dropout", "policy_std"): 0.6,
      ("mc_dropconnect", "policy_std"): 0.8,
      ("masksembles", "policy_js"): 0.71, ("ensemble", "policy_js"): 0.52, ("mc_dropout", "policy_js"): 0.61,
      ("mc_dropconnect", "policy_js"): 0.82}
SPLIT = {"value_std": (0.05, 0.2), "policy_std": (-0.3, -0.1)}


def test_each_rule_on_a_case_known_by_hand():
    spawn = _spawn({"masksembles": (1.5, 0.7), "ensemble": (1.2, 0.6), "mc_dropout": (0.9, 0.7)})
    verdicts = _verdicts(paper_claims(_vs_baseline(-8.0, 5.0), _pairwise(SPLIT), _metrics(JS),
                                      _versus([(0.01, 0.05), (-0.01, 0.02)]), spawn))
    assert verdicts == {"masksembles_reward": HOLDS,  # the worst loss the interval allows, 8, is within 10% of 100
                        "auroc_order": MIXED,  # value std: all four pairs above 0; policy std: below
                        "levitation": HOLDS,  # 2 of 3 methods on both counts
                        "js_like_std": HOLDS,  # the same order of the eight cells
                        "speed": NO_BENCHMARK,  # no benchmark with repetitions given (tests/reporting/test_speed_claim.py)
                        "members_vs_detectors": HOLDS,  # one cell above 0
                        "members_vs_pedm": PEDM_NOT_SCORED}  # no PEDM-protocol scores given (tests/reporting/test_pedm_claim.py)


def test_the_opposite_cases_and_what_cannot_be_tested_yet():
    reversed_js = {**JS, ("masksembles", "policy_js"): 0.52, ("ensemble", "policy_js"): 0.82,
                   ("mc_dropout", "policy_js"): 0.71, ("mc_dropconnect", "policy_js"): 0.61}
    behind = {"value_std": (-0.2, -0.05), "policy_std": (-0.3, -0.1)}
    verdicts = _verdicts(paper_claims(_vs_baseline(-40.0, -15.0), _pairwise(behind), _metrics(reversed_js),
                                      _versus([(-0.05, -0.01)]), None))
    assert verdicts["masksembles_reward"] == FAILS and verdicts["members_vs_detectors"] == FAILS
    assert verdicts["auroc_order"] == FAILS
    assert verdicts["levitation"] == UNTESTED and verdicts["js_like_std"] == FAILS  # reversed ranks within each env
    no_mc = _pairwise(SPLIT).query("versus != 'mc_dropconnect'")
    verdicts = _verdicts(paper_claims(_vs_baseline(-5.0, 5.0), no_mc, _metrics({("masksembles", "value_std"): 0.5}), _versus([(0.0, 0.1)]), None))
    assert verdicts["auroc_order"] == UNTESTED and verdicts["js_like_std"] == UNTESTED


def test_absence_of_evidence_is_not_agreement():
    """An interval from half the baseline's reward lost to a small gain, or one that straddles 0, decides nothing."""
    verdicts = _verdicts(paper_claims(_vs_baseline(-50.0, 5.0), _pairwise({"value_std": (-0.05, 0.2),
                                                                            "policy_std": (-0.05, 0.2)}),
                                      _metrics(JS), _versus([(-0.1, 0.1)]), None))
    assert verdicts["masksembles_reward"] == verdicts["auroc_order"] == "inconclusive (3 seeds)"
    assert verdicts["members_vs_detectors"] == "inconclusive (3 seeds)"
    one_seed = _verdicts(paper_claims(_vs_baseline(1.0, 5.0, n_seeds=1), _pairwise(SPLIT, n_seeds=1), _metrics(JS),
                                      _versus([(0.01, 0.05)], n_seeds=1), None))
    assert one_seed["masksembles_reward"] == one_seed["auroc_order"] == one_seed["members_vs_detectors"] \
        == "inconclusive (1 seed)"


def test_one_of_many_cells_clearing_zero_alone_is_not_enough_to_hold():
    """Twelve 95% intervals give twelve chances: "some cell beats the detector" needs the simultaneous interval,
    while "every cell loses" needs each cell's own interval below 0 (all must: no correction)."""
    args = (_vs_baseline(-5.0, 5.0), _pairwise(SPLIT), _metrics(JS))
    own = [(0.018, 0.070)] + [(-0.1, 0.05)] * 11  # one cell above 0 at 95% ...
    wide = [(-0.05, 0.14)] + [(-0.3, 0.2)] * 11  # ... but not once the 12 chances are accounted for
    assert _verdicts(paper_claims(*args, _versus(own, family=wide), None))["members_vs_detectors"] \
        == "inconclusive (3 seeds)"
    assert _verdicts(paper_claims(*args, _versus(own, family=[(0.001, 0.09)] + wide[1:]), None))[
        "members_vs_detectors"] == HOLDS
    below = [(-0.2, -0.01)] * 12
    assert _verdicts(paper_claims(*args, _versus(below, family=[(-0.4, 0.1)] * 12), None))[
        "members_vs_detectors"] == FAILS
    stale = _versus(own).drop(columns=["family_ci_low"])
    with pytest.raises(ValueError, match="rebuild it first"):
        paper_claims(*args, stale, None)


def test_a_claim_that_holds_names_the_cell_that_decides_it():
    """Ant after its 4th masksembles seed: a wide cell had the largest difference, a tight one decided "holds"."""
    versus = _versus([(0.03, 0.05), (-0.2, 0.4)], family=[(0.005, 0.079), (-0.47, 0.68)])
    row = detector_claim(versus)[0]
    assert row["verdict"] == HOLDS
    assert "deciding cell masksembles m0 (3 seeds) +0.040 [+0.030, +0.050], simultaneous over 2 [+0.005, +0.079]" \
        in row["evidence"]
    undecided = detector_claim(_versus([(0.03, 0.05), (-0.2, 0.4)], family=[(-0.01, 0.09), (-0.47, 0.68)]))[0]
    assert "best masksembles m1 (3 seeds) +0.10" in undecided["evidence"]  # no cell decides: the largest difference
    assert "best masksembles m0 (1 seed) +0.04" in detector_claim(_versus([(0.03, 0.05)], n_seeds=1))[0]["evidence"]


# ---------------------------------------------------------------- issue 66: the second pass, on constructed cases

PLAN = ClaimDesign(planned_seeds={"MuJoCo": 5, "Atari": 3},
                   seeds_needed={("masksembles_reward", "Swimmer-v5"): 10.0, ("auroc_order", "Swimmer-v5"): 4.0,
                                 ("members_vs_detectors", "Swimmer-v5"): np.inf})


def test_a_significant_loss_inside_the_margin_is_named_not_hidden():
    """-931 [-1846, -16] against -296: the interval is below 0 (a loss) but reaches past the margin both ways."""
    row = reward_claim(_vs_baseline(-1846.0, -16.0, baseline=2961.0))[0]
    assert row["verdict"] == "inconclusive (3 seeds)"
    assert "a significant loss (31% of the baseline's reward" in row["evidence"]
    assert "significant" not in reward_claim(_vs_baseline(-400.0, 50.0, baseline=2961.0))[0]["evidence"]


def test_three_distinct_ood_conditions_are_not_testable_however_tight_the_interval():
    """MsPacman's 3 mazes: a detector at AUROC 1 and differences of +-0.00 are no comparison."""
    mazes = _metrics(JS, conditions=3)
    tight = _versus([(-0.001, 0.001)] * 4)
    verdict = detector_claim(tight, metrics=mazes)[0]["verdict"]
    assert verdict == "not testable (3 distinct OOD conditions; needs at least 5)"
    assert auroc_claim(_pairwise(SPLIT), metrics=mazes)[0]["verdict"].startswith("not testable")
    assert detector_claim(tight, metrics=_metrics(JS, conditions=5))[0]["verdict"] == "inconclusive (3 seeds)"


def test_the_seed_plan_labels_undecided_and_decided_cells():
    """Short of the plan: provisional; at the plan: undecidable where the registered count exceeds it."""
    assert reward_claim(_vs_baseline(-50.0, 5.0), PLAN)[0]["verdict"] == "inconclusive, provisional (3 of 5 seeds)"
    assert reward_claim(_vs_baseline(-8.0, 5.0), PLAN)[0]["verdict"] == "holds, provisional (3 of 5 seeds)"
    at_plan = reward_claim(_vs_baseline(-50.0, 5.0, n_seeds=5), PLAN)[0]["verdict"]
    assert at_plan == "undecidable at 5 seeds (needs about 10)"
    assert reward_claim(_vs_baseline(-8.0, 5.0, n_seeds=5), PLAN)[0]["verdict"] == HOLDS  # decided anyway
    beyond = detector_claim(_versus([(-0.1, 0.1)], n_seeds=5), PLAN)[0]["verdict"]
    assert beyond == "undecidable at 5 seeds (needs over 200)"
    sized = auroc_claim(_pairwise({"value_std": (-0.05, 0.2), "policy_std": (-0.05, 0.2)}, n_seeds=5), PLAN)
    assert sized[0]["verdict"] == "inconclusive (5 seeds)"  # the plan was enough: a genuine no-decision
    assert base_verdict(at_plan) == "undecidable" and base_verdict("holds, provisional (3 of 5 seeds)") == HOLDS


def test_the_js_claim_has_an_interval_and_keeps_the_env_families_apart():
    """A point rho near 0.9 decides nothing; MuJoCo and Atari read apart."""
    mixed = {**JS, ("masksembles", "policy_js"): 0.5}  # one cell out of order
    rows = js_claim(_metrics(mixed, envs=("Swimmer-v5", "Walker2d-v5", "SeaquestNoFrameskip-v4",
                                          "BerzerkNoFrameskip-v4")))
    assert [r["env"] for r in rows] == ["MuJoCo", "Atari"]
    for row in rows:
        low, high = (float(x) for x in row["evidence"].split("[")[1].split("]")[0].split(", "))
        assert low < 0.9 <= high and row["verdict"] == "inconclusive (3 seeds)"


def test_the_spawn_claim_reads_intervals_over_seeds_not_point_ratios():
    """Every point ratio above 1 and AUROC above 0.5, but seeds that disagree: no verdict (the old rule: holds)."""
    noisy = _spawn({"masksembles": (1.5, 0.7), "ensemble": (1.2, 0.6), "mc_dropout": (1.1, 0.6)}, spread=0.4)
    assert levitation_claim(noisy)[0]["verdict"] == "inconclusive (3 seeds)"
    below = _spawn({"masksembles": (1.5, 0.3), "ensemble": (1.2, 0.2), "mc_dropout": (1.1, 0.6)})
    assert levitation_claim(below)[0]["verdict"] == FAILS  # 2 of 3 methods surely lower in the air
    with pytest.raises(ValueError, match="one row per run"):
        levitation_claim(noisy.drop(columns="seed"))


def test_the_registered_defaults_are_params_yaml_s():
    """ClaimDesign() (what unit tests use) and the registration in params.yaml say the same."""
    from paper_lib.pipeline.config import read_params
    from paper_lib.reporting.preregistration import Preregistration

    prereg = Preregistration.from_params(read_params())
    default = ClaimDesign()
    assert (prereg.level, prereg.reward_margin, prereg.js_threshold, prereg.min_ood_conditions) == \
        (default.level, default.reward_margin, default.js_threshold, default.min_ood_conditions)


def test_the_auroc_order_says_which_states_it_compared():
    """The registered comparison is on the baseline's states; the own-states table says it is not that one."""
    common = auroc_claim(_pairwise(SPLIT).assign(states="common"))[0]["evidence"]
    own = auroc_claim(_pairwise(SPLIT).assign(states="own"))[0]["evidence"]
    assert "one common state set per (env, seed)" in common and "own states" in own
