"""The paper's claims, each checked on our tables: one row per (claim, env) with a verdict and its numbers.

Issue 10 asks for "an honest reading": which of the paper's claims hold here and which do not. The
verdict rules are fixed here, before reading the numbers, and every row carries the numbers it rests
on, so a reader can disagree with a rule without re-running anything. Notebook 6 writes the table
(`tables/paper_claims`) and scripts/readme_results.py pastes it into docs/results.md.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

HOLDS, FAILS, MIXED, UNTESTED = "holds", "does not hold", "mixed", "not testable yet"
CLAIMS = {
    "masksembles_reward": "Masksembles keeps the baseline's reward (section 5)",
    "auroc_order": "Masksembles and Ensembles detect OOD better than MC Dropout and MC DropConnect (Table 2)",
    "levitation": "Ant: value uncertainty flags detachment from the floor at spawn (section 6)",
    "js_like_std": "The Jensen-Shannon measure ranks the methods like policy std (appendix D)",
    "members_vs_detectors": "(ours) The agent's own uncertainty beats the best member-free detector on the same states",
}
COLUMNS = ["claim", "env", "verdict", "evidence"]
SPREAD_MEASURES = ("value_std", "policy_std")


def _row(claim: str, env: str, verdict: str, evidence: str) -> dict[str, str]:
    return {"claim": CLAIMS[claim], "env": env, "verdict": verdict, "evidence": evidence}


def reward_claim(vs_baseline: pd.DataFrame) -> list[dict[str, str]]:
    """Per env: holds unless the 95% CI of Masksembles (combined) minus the baseline, sampled actions, is below 0."""
    rows = []
    cells = vs_baseline[(vs_baseline.method == "masksembles") & (vs_baseline.inference == "combined")]
    for r in cells.to_dict("records"):
        sampled = [r[f"sampled {c}"] for c in ("difference", "ci_low", "ci_high")]
        deterministic = [r[f"deterministic {c}"] for c in ("difference", "ci_low", "ci_high")]
        if np.isnan(sampled[0]):
            continue
        verdict = FAILS if sampled[2] < 0 else HOLDS
        rows.append(_row("masksembles_reward", r["env"], verdict,
                         f"Masksembles - baseline, sampled {sampled[0]:+.0f} [{sampled[1]:+.0f}, {sampled[2]:+.0f}], "
                         f"deterministic {deterministic[0]:+.0f} [{deterministic[1]:+.0f}, {deterministic[2]:+.0f}] "
                         f"({r['n_seeds']} seed(s))"))
    return rows


def auroc_claim(metrics: pd.DataFrame) -> list[dict[str, str]]:
    """Per env, on perturbed states: is the worse of Masksembles/Ensemble above the better of the MC methods?

    Checked for value_std and policy_std separately, on the cells' 95% CIs (cluster bootstrap, pooled over
    seeds): ahead if the worse cell's CI lies above the better MC cell's CI, behind if below, tied if they
    overlap. Holds if ahead for both measures, mixed if for one, does not hold if for neither.
    """
    perturbed = metrics[(metrics.ood_set == "perturbed") & metrics.measure.isin(SPREAD_MEASURES)]
    cells = perturbed.groupby(["env", "measure", "method"])[["auroc", "auroc_ci_low", "auroc_ci_high"]].mean()
    rows = []
    for env_id in pd.unique(perturbed.env):
        wins, parts = [], []
        for measure in SPREAD_MEASURES:
            if (env_id, measure) not in cells.index.droplevel("method"):
                continue
            cell = cells.loc[(env_id, measure)]
            ahead = cell.reindex(["masksembles", "ensemble"]).dropna(subset=["auroc"])
            behind = cell.reindex(["mc_dropout", "mc_dropconnect"]).dropna(subset=["auroc"])
            if ahead.empty or behind.empty:
                continue
            worse, better = ahead.loc[ahead.auroc.idxmin()], behind.loc[behind.auroc.idxmax()]
            order = ("ahead" if worse.auroc_ci_low > better.auroc_ci_high else
                     "behind" if worse.auroc_ci_high < better.auroc_ci_low else "tied")
            wins.append(order == "ahead")
            parts.append(f"{measure} ({order}): " + ", ".join(f"{m} {v:.2f}" for m, v in
                                                             pd.concat([ahead.auroc, behind.auroc]).items()))
        verdict = UNTESTED if not wins else HOLDS if all(wins) else FAILS if not any(wins) else MIXED
        rows.append(_row("auroc_order", env_id, verdict, "; ".join(parts) or "needs a run of each group"))
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
    """Per env, perturbed states: member cells whose 95% CI of (measure - best detector) is above 0 / contains 0 / below."""
    rows = []
    for env_id, cells in versus[versus.ood_set == "perturbed"].groupby("env", sort=False):
        above, below = int((cells.ci_low > 0).sum()), int((cells.ci_high < 0).sum())
        tied = len(cells) - above - below
        verdict = HOLDS if above and not below else FAILS if below and not above else MIXED if above else FAILS
        best = cells.loc[cells.difference.idxmax()]
        rows.append(_row("members_vs_detectors", env_id, verdict,
                         f"of {len(cells)} measure cells: {above} above the detector, {tied} tied, {below} below; "
                         f"best {best.method} {best.measure} {best.difference:+.2f} vs {best.detector}"))
    return rows


def paper_claims(vs_baseline: pd.DataFrame, metrics: pd.DataFrame, versus: pd.DataFrame,
                 spawn: pd.DataFrame | None) -> pd.DataFrame:
    """Every claim's rows, in the order of ``CLAIMS``."""
    rows = (reward_claim(vs_baseline) + auroc_claim(metrics) + levitation_claim(spawn) + js_claim(metrics)
            + detector_claim(versus))
    return pd.DataFrame(rows, columns=COLUMNS)
