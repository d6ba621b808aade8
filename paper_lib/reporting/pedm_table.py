"""PEDM's protocol as a table (issue 69, notebook 14): every scorer of every MuJoCo run, per severity.

Each run's `pedm` stage wrote its metrics (results/<profile>/pedm/<env>/<method>/seed<s>/metrics.csv): per scorer
(the agent's own measures, PEDM and the two sequence baselines) and per (kind, severity), PEDM's pooled per-step
AUROC, AP and FPR@95, plus kind ``mean``, PEDM's per-severity mean over its 5 kinds; `pedm_runs.protocol_runs` adds
what it computes from each run's steps.npz (`pedm_scores.step_metrics`): the time-matched AUROC, the detection delay
and the ``clock``, the step index as a scorer (a reference column: what PEDM's pooled AUROC gives for knowing only
the time). The table puts one row per (env, method, severity) and one column per scorer; a cell is the mean over the
seeds of that per-severity mean, with Student's t 95% interval over the seeds where there are two or more, cut to
[0, 1] (the cut part holds no possible AUROC), and the seed count, as "0.95 [0.91, 0.99] (n=4)". Rows run down
rather than severities across: 6 scorers x 2 severities side by side would not fit the site's column
(docs/deviations.md). `pedm_runs.protocol_runs` reads the long form every cell is computed from, one row per (run,
scorer, kind, severity), written beside the table so any reader can recompute it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from paper_lib.common.io import write_text_atomic
from paper_lib.measures.definitions import ALL_MEMBER_MEASURES
from paper_lib.reporting.tables import csv_text, save_table
from paper_lib.scoring.pedm_scores import CLOCK
from paper_lib.scoring.peer_scores import PEER_DETECTORS
from paper_lib.scoring.statistics import t_interval

#: The long form: one row per (run, scorer, kind, severity); kind ``mean`` is PEDM's per-severity mean.
RUN_COLUMNS = ("env", "method", "seed", "scorer", "kind", "severity", "auroc", "aupr_out", "fpr_at_95_tpr",
               "auroc_time_matched", "delay_median", "detected", "false_alarm", "false_alarm_bound")
#: One cell of the table before it is printed: the mean over seeds of the per-severity mean AUROC, its interval.
CELL_COLUMNS = ("env", "method", "severity", "scorer", "auroc", "ci_low", "ci_high", "n_seeds")
MEAN_KIND = "mean"
SEVERITY_ORDER = ("minor", "severe")
#: What the table says when no run of the profile has played PEDM's protocol.
NO_RUNS = ("no MuJoCo run of this profile has PEDM-protocol metrics yet: give one a stage with `python -m "
           "paper_lib.pipeline.run_list --pedm ENV METHOD SEED`, then `dvc repro -s pedm@ENV-METHOD-SEED`")
#: PEDM's test episodes per kind and severity (pedm-ood, oodd_runner.py: n_test_episodes=100).
PEDM_TEST_EPISODES = 100


def scorer_order(scorers: list[str] | pd.Series) -> list[str]:
    """The scorers found, the agent's own measures first (ALL_MEMBER_MEASURES), then PEER_DETECTORS, then others,
    the CLOCK (a reference) last."""
    found = list(dict.fromkeys(scorers))
    known = [*ALL_MEMBER_MEASURES, *PEER_DETECTORS]
    ordered = [s for s in known if s in found] + [s for s in found if s not in known and s != CLOCK]
    return ordered + [CLOCK] * (CLOCK in found)


def _check_runs(runs: pd.DataFrame) -> None:
    missing = [c for c in RUN_COLUMNS if c not in runs.columns]
    if missing:
        raise ValueError(f"PEDM's protocol table needs the long form with columns {list(RUN_COLUMNS)}; {missing} are "
                         "missing: read it with `pedm_runs.protocol_runs`")


def severity_cells(runs: pd.DataFrame, level: float = 0.95) -> pd.DataFrame:
    """CELL_COLUMNS: per (env, method, severity, scorer), the mean over seeds of the per-severity mean AUROC (kind
    ``mean``), Student's t interval over the seeds cut to [0, 1] (NaN with one seed) and the number of seeds.

    At 2 seeds t's 0.975 quantile is 12.7: an interval such as [-0.07, 1.77] would reach past what an AUROC can be,
    and the part cut off holds no possible value."""
    _check_runs(runs)
    means = runs[runs["kind"] == MEAN_KIND]
    twice = means.duplicated(["env", "method", "seed", "scorer", "severity"])
    if twice.any():
        first = means[twice].iloc[0]
        raise ValueError(f"PEDM's protocol holds {first.env} {first.method} seed {first.seed} {first.scorer} "
                         f"{first.severity} more than once: one metrics.csv per run")
    rows = []
    for (env, method, severity, scorer), cell in means.groupby(["env", "method", "severity", "scorer"], sort=False):
        aurocs = cell["auroc"].to_numpy(dtype=float)
        low, high = np.clip(t_interval(aurocs, level), 0.0, 1.0) if aurocs.size >= 2 else (np.nan, np.nan)
        rows.append({"env": env, "method": method, "severity": severity, "scorer": scorer,
                     "auroc": float(aurocs.mean()), "ci_low": float(low), "ci_high": float(high),
                     "n_seeds": int(aurocs.size)})
    return pd.DataFrame(rows, columns=list(CELL_COLUMNS))


def cell_text(auroc: float, low: float, high: float, n_seeds: int, digits: int = 2) -> str:
    """'0.95 [0.91, 0.99] (n=4)'; with one seed (no interval) '0.95 (n=1)'."""
    interval = "" if np.isnan(low) or np.isnan(high) else f" [{low:.{digits}f}, {high:.{digits}f}]"
    return f"{auroc:.{digits}f}{interval} (n={n_seeds})"


def protocol_table(runs: pd.DataFrame, digits: int = 2) -> pd.DataFrame:
    """One row per (env, method, severity), one column per scorer (`scorer_order`), each cell `cell_text`; empty
    where a run has no such scorer (a baseline has no measure of its own). No runs: one row saying so (NO_RUNS)."""
    cells = severity_cells(runs)
    if cells.empty:
        return pd.DataFrame({"PEDM's protocol": [NO_RUNS]})
    cells["cell"] = [cell_text(*values, digits=digits) for values in
                     cells[["auroc", "ci_low", "ci_high", "n_seeds"]].itertuples(index=False)]
    keys = ["env", "method", "severity"]
    rank = {key: {v: i for i, v in enumerate(pd.unique(cells[key]))} for key in ("env", "method")}
    rank["severity"] = {s: i for i, s in enumerate(SEVERITY_ORDER)}  # envs and methods as read, minor before severe
    rows = cells[keys].drop_duplicates().sort_values(keys, key=lambda col: col.map(rank[col.name]), kind="stable")
    table = cells.pivot(index=keys, columns="scorer", values="cell")
    table = table.reindex(index=pd.MultiIndex.from_frame(rows), columns=scorer_order(cells["scorer"]))
    table.columns.name = None
    return table.fillna("").reset_index()


def table_caption(runs: pd.DataFrame, profile: str) -> str:
    """The table's caption: what a cell is, and how many runs per env it rests on (computed from `runs`)."""
    what = ("AUROC under PEDM's protocol (a perturbation injected at a random step of each episode; pooled per-step "
            "AUROC of one kind and severity, averaged over PEDM's 5 kinds per severity, as PEDM reports it): mean over "
            "seeds, Student's t 95% interval over seeds where there are two or more, cut to [0, 1] (the part cut off "
            "holds no possible AUROC), (n=seeds); clock: the step index alone as a score, a reference (perturbed "
            "steps come later in an episode; no claim uses it); empty: the run has no such score (a baseline has no "
            f"measure of its own) (profile {profile!r}")
    if runs.empty:
        return f"{what}; no run has played it yet)."
    per_env = runs.drop_duplicates(["env", "method", "seed"]).groupby("env", sort=False).size()
    return f"{what}; runs per env: {', '.join(f'{env} {n}' for env, n in per_env.items())})."


def save_protocol_tables(runs: pd.DataFrame, table_stem: Path, runs_csv: Path, profile: str) -> pd.DataFrame:
    """Write the table (csv, md, tex at `table_stem`) and the long form beside it (`runs_csv`); return the table."""
    table = protocol_table(runs)
    save_table(table, table_stem, table_caption(runs, profile))
    write_text_atomic(runs_csv, csv_text(runs.sort_values(["env", "method", "seed"], kind="stable")))
    return table
