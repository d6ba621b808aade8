"""Claim 7, "(ours) the agents' own uncertainty beats PEDM on PEDM's protocol", as a verdict.

Registered on 2026-12-05 (params.yaml `preregistration.pedm`, docs/preregistration.md) before any PEDM-protocol
episode was played or scored. Each run plays PEDM's protocol and fits its own PEDM (issue 69); a run's AUROC of a
score is PEDM's metric, the per-step AUROC pooled over the run's episodes of one (kind, severity), averaged over the
kinds per severity and then over the severities. A cell is a (member method, agent measure) pair, as in claim 5;
its per-seed difference to PEDM on the same run's transitions is paired, and its interval is Student's t over the
seeds (the floor every interval over seeds keeps), beside the one simultaneous over the env's m cells (Bonferroni).
The verdict is claim 5's (`claims.detector_claim`), read here on these differences.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from paper_lib.measures.definitions import ALL_MEMBER_MEASURES
from paper_lib.reporting.claims import CLAIMS, LEVEL, ClaimDesign, detector_claim
from paper_lib.scoring.statistics import t_interval

#: The detector every cell is paired against, and the OOD set the rows are filed under.
VERSUS, OOD_SET = "pedm", "pedm_protocol"
#: Per-run AUROCs, one row per (run, score): PEDM's metric for the run (`auroc`), whatever wrote it.
RUN_AUROC_COLUMNS = ("env", "method", "seed", "measure", "auroc")
NOT_SCORED = "not testable (no member run has PEDM-protocol scores yet)"


def _check(run_aurocs: pd.DataFrame) -> None:
    missing = [c for c in RUN_AUROC_COLUMNS if c not in run_aurocs.columns]
    if missing:
        raise ValueError(f"the PEDM claim needs per-run AUROCs with columns {list(RUN_AUROC_COLUMNS)}; {missing} are "
                         "missing: rebuild the PEDM-protocol table first (its notebook runs before notebook 6)")
    twice = run_aurocs.duplicated(["env", "method", "seed", "measure"])
    if twice.any():
        first = run_aurocs[twice].iloc[0]
        raise ValueError(f"the PEDM-protocol AUROCs hold {first.env} {first.method} seed {first.seed} "
                         f"{first.measure} more than once: one row per run and score")


def _interval(differences: np.ndarray, level: float) -> tuple[float, float]:
    return t_interval(differences, level) if differences.size >= 2 else (np.nan, np.nan)


def pedm_versus(run_aurocs: pd.DataFrame, level: float = LEVEL) -> pd.DataFrame:
    """Each (env, member method, agent measure) cell's AUROC minus PEDM's on the same runs, per seed, with its t
    interval and the one simultaneous over the env's cells: the columns `claims.detector_claim` reads."""
    _check(run_aurocs)
    rows = []
    for env, runs in run_aurocs.groupby("env", sort=False):
        pedm = runs[runs.measure == VERSUS].set_index(["method", "seed"])["auroc"]
        members = runs[runs.measure.isin(ALL_MEMBER_MEASURES)]
        cells = list(members.groupby(["method", "measure"], sort=False))
        for (method, measure), cell in cells:
            own = cell.set_index(["method", "seed"])["auroc"]
            paired = own.index.intersection(pedm.index)
            d = (own[paired] - pedm[paired]).to_numpy(dtype=float)
            low, high = _interval(d, level)
            family_low, family_high = _interval(d, 1.0 - (1.0 - level) / len(cells))
            rows.append({"env": env, "ood_set": OOD_SET, "method": method, "measure": measure,
                         "auroc": float(own[paired].mean()), "detector": VERSUS,
                         "detector_auroc": float(pedm[paired].mean()), "difference": float(d.mean()) if d.size else np.nan,
                         "ci_low": low, "ci_high": high, "family_size": len(cells), "family_ci_low": family_low,
                         "family_ci_high": family_high, "n_seeds": int(d.size)})
    return pd.DataFrame(rows)


def pedm_rows(run_aurocs: pd.DataFrame | None, design: ClaimDesign = ClaimDesign(),
              envs: list[str] | None = None) -> list[dict[str, str]]:
    """The claims table's rows of claim 7, one per MuJoCo env of `envs` (default: those with PEDM-protocol AUROCs):
    claim 5's verdict where some member run has them, otherwise not testable, saying how many runs have any."""
    from paper_lib.agents.envs import is_atari

    if run_aurocs is None or run_aurocs.empty:
        run_aurocs = pd.DataFrame(columns=list(RUN_AUROC_COLUMNS))
    versus = pedm_versus(run_aurocs, design.level) if not run_aurocs.empty else pd.DataFrame(columns=["env"])
    decided = {row["env"]: row for row in (detector_claim(versus, design, None, claim="members_vs_pedm",
                                                          ood_set=OOD_SET) if not versus.empty else [])}
    wanted = [env for env in (envs if envs is not None else run_aurocs["env"].unique()) if not is_atari(env)]
    rows = []
    for env in dict.fromkeys([*wanted, *decided]):
        if env in decided:
            rows.append(decided[env])
            continue
        runs = len(run_aurocs[run_aurocs["env"] == env].groupby(["method", "seed"]))
        rows.append({"claim": CLAIMS["members_vs_pedm"], "env": env, "verdict": NOT_SCORED,
                     "evidence": f"{runs} run(s) have PEDM-protocol scores, none of a member method (the `pedm` "
                                 "stages, issue 69)"})
    return rows
