"""The paper's claims, each checked on our tables: one row per (claim, env) with a verdict and its numbers.

Issue 10 asks for "an honest reading": which of the paper's claims hold here and which do not. The
verdict rules are fixed here, before reading the numbers, and every row carries the numbers it rests
on, so a reader can disagree with a rule without re-running anything.

The claims that rest on an interval share one rule shape (`decide`), the same burden of proof either way:
"holds" when the 95% interval excludes failure, "does not hold" when it excludes success, "inconclusive
(n seeds)" otherwise. A cell of one training seed is inconclusive whatever its interval: that interval
covers the episodes or states of one run, not the method. Where one of m cells alone would decide (some cell
beats the detector; some pair is behind), that cell's interval is simultaneous over the m (Bonferroni, the
tables' `family_ci_*`), so that m chances do not tilt the verdict that way. Notebook 6 writes the table
(`tables/paper_claims`) and scripts/readme_results.py pastes it into docs/results.md.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

HOLDS, FAILS, MIXED, UNTESTED = "holds", "does not hold", "mixed", "not testable yet"
#: "Keeps the baseline's reward" fails on a loss larger than this share of the baseline's reward (sampled actions).
REWARD_MARGIN = 0.10
#: The paper's AUROC-order claim: each of these methods against each of the MC methods.
AHEAD, BEHIND = ("masksembles", "ensemble"), ("mc_dropout", "mc_dropconnect")
AUROC_ORDER_PAIRS = [(a, b) for a in AHEAD for b in BEHIND]
CLAIMS = {
    "masksembles_reward": "Masksembles keeps the baseline's reward (section 5)",
    "auroc_order": "Masksembles and Ensembles detect OOD better than MC Dropout and MC DropConnect (Table 2)",
    "levitation": "Ant: value uncertainty flags detachment from the floor at spawn (section 6)",
    "js_like_std": "The Jensen-Shannon measure ranks the methods like policy std (appendix D)",
    "members_vs_detectors": "(ours) The agent's own uncertainty beats the best member-free detector on the same states",
}
COLUMNS = ["claim", "env", "verdict", "evidence"]
SPREAD_MEASURES = ("value_std", "policy_std")


def inconclusive(n_seeds: int) -> str:
    return f"inconclusive ({n_seeds} seed{'' if n_seeds == 1 else 's'})"


def decide(ci_low: float, ci_high: float, failure_below: float, n_seeds: int) -> str:
    """The one rule: success is a difference at or above `failure_below`, failure one below it.

    Holds when the interval excludes failure (ci_low >= failure_below), does not hold when it excludes
    success (ci_high < failure_below), inconclusive otherwise or with fewer than 2 seeds.
    """
    if n_seeds < 2:
        return inconclusive(n_seeds)
    if ci_low >= failure_below:
        return HOLDS
    if ci_high < failure_below:
        return FAILS
    return inconclusive(n_seeds)


def combine(verdicts: list[str], n_seeds: int) -> str:
    """Several verdicts of one claim (e.g. per measure): holds if all hold, does not hold if all fail."""
    if not verdicts:
        return UNTESTED
    if all(v == HOLDS for v in verdicts):
        return HOLDS
    if all(v == FAILS for v in verdicts):
        return FAILS
    if HOLDS in verdicts and FAILS in verdicts:
        return MIXED
    return inconclusive(n_seeds)


def _row(claim: str, env: str, verdict: str, evidence: str) -> dict[str, str]:
    return {"claim": CLAIMS[claim], "env": env, "verdict": verdict, "evidence": evidence}


def reward_claim(vs_baseline: pd.DataFrame) -> list[dict[str, str]]:
    """Per env, non-inferiority: Masksembles (combined) minus the baseline, sampled actions as the paper's Table 1.

    Failure is a loss larger than `REWARD_MARGIN` of the baseline's reward, on the paired per-seed
    difference and its interval (`paper_tables.reward_vs_baseline`).
    """
    rows = []
    cells = vs_baseline[(vs_baseline.method == "masksembles") & (vs_baseline.inference == "combined")]
    for r in cells.to_dict("records"):
        sampled = [r[f"sampled {c}"] for c in ("difference", "ci_low", "ci_high")]
        deterministic = [r[f"deterministic {c}"] for c in ("difference", "ci_low", "ci_high")]
        if np.isnan(sampled[0]):
            continue
        margin = REWARD_MARGIN * abs(r["sampled baseline"])
        n_seeds = int(r["n_seeds"])
        played = (f"deterministic {deterministic[0]:+.0f} [{deterministic[1]:+.0f}, {deterministic[2]:+.0f}]"
                  if np.isfinite(deterministic[0]) else "deterministic not played (sampled only)")
        rows.append(_row("masksembles_reward", r["env"], decide(sampled[1], sampled[2], -margin, n_seeds),
                         f"Masksembles - baseline, sampled {sampled[0]:+.0f} [{sampled[1]:+.0f}, {sampled[2]:+.0f}] "
                         f"against the margin {-margin:+.0f} ({REWARD_MARGIN:.0%} of the baseline's "
                         f"{r['sampled baseline']:.0f}); {played}; {n_seeds} seed(s)"))
    return rows


def _require_family_intervals(table: pd.DataFrame, name: str) -> None:
    """One clear error for a table written before it carried its simultaneous intervals."""
    missing = sorted({"family_size", "family_ci_low", "family_ci_high"} - set(table.columns))
    if missing:
        raise ValueError(f"the claims need tables/{name} with {missing}, which older code did not write; rebuild "
                         "it first: `make reproduce` runs notebook 3 before notebook 6.")


def auroc_claim(pairwise: pd.DataFrame) -> list[dict[str, str]]:
    """Per env, perturbed states: Masksembles and Ensemble each above MC Dropout and MC DropConnect.

    For value_std and policy_std separately, on the per-seed AUROC differences of the four pairs
    (`paper_tables.auroc_between_methods`): a measure holds when all four intervals lie above 0 (all must, so
    each pair's own 95% interval), does not hold when some pair's simultaneous interval over the four lies below 0
    (one of four chances: Bonferroni, the same 5% risk as the other way); the two measures combine with `combine`.
    """
    _require_family_intervals(pairwise, "auroc_between_methods")
    rows = []
    perturbed = pairwise[pairwise.ood_set == "perturbed"]
    for env_id in pd.unique(perturbed.env):
        verdicts, parts, seeds = [], [], []
        for measure in SPREAD_MEASURES:
            cells = perturbed[(perturbed.env == env_id) & (perturbed.measure == measure)]
            cells = cells.set_index(["method", "versus"]).reindex(AUROC_ORDER_PAIRS).dropna(subset=["difference"])
            if len(cells) < len(AUROC_ORDER_PAIRS):
                continue
            n_seeds = int(cells.n_seeds.min())
            seeds.append(n_seeds)
            if n_seeds < 2:
                verdict = inconclusive(n_seeds)
            elif (cells.ci_low > 0).all():
                verdict = HOLDS
            elif (cells.family_ci_high < 0).any():
                verdict = FAILS
            else:
                verdict = inconclusive(n_seeds)
            verdicts.append(verdict)
            parts.append(f"{measure} ({verdict}): " + ", ".join(
                f"{a} - {b} {r.difference:+.2f} [{r.ci_low:+.2f}, {r.ci_high:+.2f}]"
                for (a, b), r in cells.iterrows()))
        rows.append(_row("auroc_order", env_id, combine(verdicts, min(seeds, default=0)),
                         "; ".join(parts) + (f"; {min(seeds)} seed(s)" if seeds else "")
                         if parts else "needs a run of each method"))
    return rows


def levitation_claim(spawn: pd.DataFrame | None) -> list[dict[str, str]]:
    """Ant: holds if most member methods have higher value std at spawn and in the air (AUROC > 0.5)."""
    ant = spawn[spawn.env == "Ant-v5"] if spawn is not None else pd.DataFrame()
    if ant.empty:
        return [_row("levitation", "Ant-v5", UNTESTED, "no Ant member-method run yet (notebook 12)")]
    both = (ant.value_std_spawn_ratio > 1) & (ant.value_std_airborne_auroc > 0.5)
    verdict = HOLDS if both.mean() > 0.5 else FAILS if not both.any() else MIXED
    evidence = "; ".join(f"{r.method}: spawn/later {r.value_std_spawn_ratio:.2f}, air AUROC {r.value_std_airborne_auroc:.2f}"
                         for r in ant.itertuples())
    return [_row("levitation", "Ant-v5", verdict, evidence + " (notebook 12)")]


def js_claim(metrics: pd.DataFrame) -> list[dict[str, str]]:
    """All envs: Spearman correlation of policy_js and policy_std AUROC over (env, method) cells, perturbed states.

    Holds at rho >= 0.9, mixed at 0.5 <= rho < 0.9, does not hold below; needs 3 cells.
    """
    perturbed = metrics[metrics.ood_set == "perturbed"]
    wide = perturbed.pivot_table(index=["env", "method"], columns="measure", values="auroc", aggfunc="mean")
    if not {"policy_js", "policy_std"} <= set(wide.columns):
        return [_row("js_like_std", "all", UNTESTED, "no member-method scores yet")]
    pairs = wide[["policy_js", "policy_std"]].dropna()
    if len(pairs) < 3:
        return [_row("js_like_std", "all", UNTESTED, f"{len(pairs)} (env, method) cell(s); needs 3")]
    rho = pairs.policy_js.rank().corr(pairs.policy_std.rank())
    gap = (pairs.policy_js - pairs.policy_std).abs()
    verdict = HOLDS if rho >= 0.9 else MIXED if rho >= 0.5 else FAILS
    return [_row("js_like_std", "all", verdict, f"Spearman rho {rho:.2f} over {len(pairs)} (env, method) cells; "
                 f"|AUROC difference| median {gap.median():.3f}, max {gap.max():.3f}")]


def detector_claim(versus: pd.DataFrame) -> list[dict[str, str]]:
    """Per env, perturbed states: does some member measure beat its runs' best member-free detector?

    Success is at least one (method, measure) cell above the detector, failure every cell below it, each at
    the same 5% risk of a wrong verdict: holds when some cell's simultaneous interval (Bonferroni over the env's
    m cells, `paper_tables.auroc_vs_detectors`) lies above 0, since any one of m 95% intervals would clear 0 by
    chance far more often than 5%; does not hold when every cell's own 95% interval lies below 0 (all m must,
    so no correction is needed); inconclusive otherwise. Cells of one seed count for neither.
    """
    _require_family_intervals(versus, "auroc_vs_detectors")
    rows = []
    for env_id, cells in versus[versus.ood_set == "perturbed"].groupby("env", sort=False):
        above, below = int((cells.ci_low > 0).sum()), int((cells.ci_high < 0).sum())
        tested = cells[cells.n_seeds >= 2]
        n_seeds = int(cells.n_seeds.min())
        if tested.empty:
            verdict = inconclusive(n_seeds)
        elif (tested.family_ci_low > 0).any():
            verdict = HOLDS
        elif len(tested) == len(cells) and (tested.ci_high < 0).all():
            verdict = FAILS
        else:
            verdict = inconclusive(n_seeds)
        best = cells.loc[cells.difference.idxmax()]
        rows.append(_row("members_vs_detectors", env_id, verdict,
                         f"of {len(cells)} measure cells (95% intervals): {above} above the detector, "
                         f"{len(cells) - above - below} tied, {below} below; best {best.method} {best.measure} "
                         f"{best.difference:+.2f} [{best.ci_low:+.2f}, {best.ci_high:+.2f}], simultaneous over "
                         f"{int(best.family_size)} [{best.family_ci_low:+.2f}, {best.family_ci_high:+.2f}] vs "
                         f"{best.detector}; {n_seeds} seed(s)"))
    return rows


def paper_claims(vs_baseline: pd.DataFrame, pairwise: pd.DataFrame, metrics: pd.DataFrame, versus: pd.DataFrame,
                 spawn: pd.DataFrame | None) -> pd.DataFrame:
    """Every claim's rows, in the order of ``CLAIMS``."""
    rows = (reward_claim(vs_baseline) + auroc_claim(pairwise) + levitation_claim(spawn) + js_claim(metrics)
            + detector_claim(versus))
    return pd.DataFrame(rows, columns=COLUMNS)
