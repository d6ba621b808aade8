"""The verdict rules of the paper's claims, on small tables whose answers are known by hand."""

from __future__ import annotations

import pandas as pd

from paper_lib.reporting.claims import CLAIMS, FAILS, HOLDS, MIXED, UNTESTED, paper_claims


def _vs_baseline(sampled_ci_high: float) -> pd.DataFrame:
    return pd.DataFrame([{"env": "Swimmer-v5", "method": "masksembles", "inference": "combined",
                          "sampled difference": sampled_ci_high - 10, "sampled ci_low": sampled_ci_high - 20,
                          "sampled ci_high": sampled_ci_high, "deterministic difference": 5.0,
                          "deterministic ci_low": 1.0, "deterministic ci_high": 9.0, "n_seeds": 1}])


def _metrics(aurocs: dict[tuple[str, str], float], half_width: float = 0.04) -> pd.DataFrame:
    """ood_metrics rows with a 95% CI of +- ``half_width`` around each AUROC."""
    return pd.DataFrame([{"env": "Swimmer-v5", "ood_set": "perturbed", "method": m, "measure": s, "auroc": a,
                          "auroc_ci_low": a - half_width, "auroc_ci_high": a + half_width}
                         for (m, s), a in aurocs.items()])


def _versus(ci: list[tuple[float, float]]) -> pd.DataFrame:
    return pd.DataFrame([{"env": "Swimmer-v5", "ood_set": "perturbed", "method": "masksembles", "measure": f"m{i}",
                          "difference": (lo + hi) / 2, "ci_low": lo, "ci_high": hi, "detector": "knn_obs"}
                         for i, (lo, hi) in enumerate(ci)])


def _verdicts(table: pd.DataFrame) -> dict[str, str]:
    return {key: table[table.claim == text].verdict.tolist()[0] for key, text in CLAIMS.items()}


ORDERED = {("masksembles", "value_std"): 0.9, ("ensemble", "value_std"): 0.8, ("mc_dropout", "value_std"): 0.6,
           ("masksembles", "policy_std"): 0.7, ("ensemble", "policy_std"): 0.5, ("mc_dropout", "policy_std"): 0.6,
           ("masksembles", "policy_js"): 0.71, ("ensemble", "policy_js"): 0.52, ("mc_dropout", "policy_js"): 0.61}


def test_each_rule_on_a_case_known_by_hand():
    spawn = pd.DataFrame([{"env": "Ant-v5", "method": m, "value_std_spawn_ratio": r, "value_std_airborne_auroc": a}
                          for m, r, a in [("masksembles", 1.5, 0.7), ("ensemble", 1.2, 0.6), ("mc_dropout", 0.9, 0.7)]])
    verdicts = _verdicts(paper_claims(_vs_baseline(5.0), _metrics(ORDERED), _versus([(0.01, 0.05), (-0.01, 0.02)]),
                                      spawn))
    assert verdicts == {"masksembles_reward": HOLDS,  # the CI reaches above 0
                        "auroc_order": MIXED,  # value std: 0.8 > 0.6, CIs apart; policy std: 0.5 < 0.6
                        "levitation": HOLDS,  # 2 of 3 methods on both counts
                        "js_like_std": HOLDS,  # the same order of the three methods
                        "members_vs_detectors": HOLDS}  # one cell above, none below


def test_the_opposite_cases_and_what_cannot_be_tested_yet():
    reversed_js = {**ORDERED, ("masksembles", "policy_js"): 0.5, ("ensemble", "policy_js"): 0.7}
    verdicts = _verdicts(paper_claims(_vs_baseline(-1.0), _metrics(reversed_js), _versus([(-0.05, -0.01)]), None))
    assert verdicts["masksembles_reward"] == FAILS and verdicts["members_vs_detectors"] == FAILS
    assert verdicts["levitation"] == UNTESTED and verdicts["js_like_std"] == FAILS  # rho = -0.5
    no_mc = {k: v for k, v in ORDERED.items() if k[0] != "mc_dropout"}
    verdicts = _verdicts(paper_claims(_vs_baseline(5.0), _metrics(no_mc), _versus([(0.0, 0.1)]), None))
    assert verdicts["auroc_order"] == UNTESTED and verdicts["js_like_std"] == UNTESTED  # 2 cells only


def test_auroc_order_needs_the_confidence_intervals_apart():
    """Ant at 1e6: 0.51 vs 0.51 is a tie, not a win; wider CIs turn the ordered case into ties."""
    ant_like = {("masksembles", "value_std"): 0.512, ("mc_dropout", "value_std"): 0.509,
                ("masksembles", "policy_std"): 0.503, ("mc_dropout", "policy_std"): 0.494}
    verdicts = _verdicts(paper_claims(_vs_baseline(5.0), _metrics(ant_like, 0.03), _versus([(0.0, 0.1)]), None))
    assert verdicts["auroc_order"] == FAILS
    verdicts = _verdicts(paper_claims(_vs_baseline(5.0), _metrics(ORDERED, 0.15), _versus([(0.0, 0.1)]), None))
    assert verdicts["auroc_order"] == FAILS  # 0.8 vs 0.6 with +-0.15: the intervals overlap
    verdicts = _verdicts(paper_claims(_vs_baseline(5.0), _metrics(ORDERED, 0.01), _versus([(0.0, 0.1)]), None))
    assert verdicts["auroc_order"] == MIXED  # apart for value std; policy std behind
