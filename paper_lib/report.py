"""Shaping result frames into the paper's tables (wide layouts, paper-vs-us comparisons)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from paper_lib.tables import PLUS_MINUS

#: Names the paper's CSVs use for our Gymnasium ids.
PAPER_ENV_NAMES = {"HalfCheetah-v5": "HalfCheetah", "Ant-v5": "Ant", "Walker2d-v5": "Walker2d", "Swimmer-v5": "Swimmer",
                   "SeaquestNoFrameskip-v4": "Seaquest", "MsPacmanNoFrameskip-v4": "MsPacman",
                   "BerzerkNoFrameskip-v4": "Berzerk", "SpaceInvadersNoFrameskip-v4": "SpaceInvaders"}


def _ordered(df: pd.DataFrame, column: str, order: list[str]) -> pd.DataFrame:
    return df.assign(**{column: pd.Categorical(df[column], [o for o in order if o in set(df[column])], ordered=True)})


def reward_table(summary: pd.DataFrame, methods: list[str]) -> pd.DataFrame:
    """Rows: method x inference x action mode; columns: env; cells 'mean ± std'.

    Where cells rest on different numbers of seeds (a partly trained profile), each cell says
    how many: 'mean ± std (n=2)'.
    """
    cells = [f"{m:.1f} {PLUS_MINUS} {s:.1f}" for m, s in zip(summary["mean"], summary["std"])]
    if "n_seeds" in summary and summary["n_seeds"].nunique() > 1:
        cells = [f"{c} (n={n})" for c, n in zip(cells, summary["n_seeds"])]
    df = summary.assign(actions=np.where(summary["deterministic"], "deterministic", "sampled"), cell=cells)
    df = _ordered(df, "method", methods)
    wide = df.pivot_table(index=["method", "inference", "actions"], columns="env", values="cell", aggfunc="first",
                          observed=True)
    return wide.reset_index().rename_axis(columns=None)


def auroc_table(metrics: pd.DataFrame, methods: list[str], value: str = "auroc") -> pd.DataFrame:
    """Rows: method x measure; columns: env; cells: mean over seeds of `value` (Table 2 layout)."""
    df = _ordered(metrics, "method", methods)
    wide = df.pivot_table(index=["method", "measure"], columns="env", values=value, aggfunc="mean", observed=True)
    return wide.reset_index().rename_axis(columns=None)


def read_reported(folder: str | Path, name: str) -> pd.DataFrame:
    """One of the paper's reported tables (data/paper_reported/reported_<name>.csv), in long form."""
    path = Path(folder) / f"reported_{name}.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing; it is copied from ../shared/paper/ and committed with the project")
    df = pd.read_csv(path)
    id_cols = [c for c in df.columns if c not in PAPER_ENV_NAMES.values()]
    long = df.melt(id_vars=id_cols, var_name="paper_env", value_name="paper").dropna(subset=["paper"])
    inverse = {v: k for k, v in PAPER_ENV_NAMES.items()}
    return long.assign(env=long["paper_env"].map(inverse)).drop(columns="paper_env")


def compare_with_paper(ours: pd.DataFrame, reported: pd.DataFrame, keys: list[str], value: str) -> pd.DataFrame:
    """Our `value` beside the paper's for every key both have, with the difference (ours - paper)."""
    merged = ours.rename(columns={value: "ours"}).merge(reported, on=[*keys, "env"], how="inner")
    return merged.assign(difference=merged["ours"] - merged["paper"])[[*keys, "env", "ours", "paper", "difference"]]


def seeds_per_cell(df: pd.DataFrame, cell: list[str], seed: str = "seed") -> str:
    """How many seeds stand behind each table cell: '1 seed per cell', or per env when cells differ.

    A partly trained profile (some seeds missing) gives cells with different counts; the
    caption says so instead of implying every cell has the profile's seeds.
    """
    counts = df.groupby(cell, observed=True)[seed].nunique()
    if counts.empty:
        return "no seeds"
    low, high = int(counts.min()), int(counts.max())
    if low == high:
        return f"{low} seed{'s' if low != 1 else ''} per cell"
    if "env" in cell:
        per_env = counts.groupby(level="env", sort=False).agg(["min", "max"])
        parts = [f"{env} {lo}" if lo == hi else f"{env} {lo} to {hi}" for env, (lo, hi) in per_env.iterrows()]
        return "seeds per cell: " + ", ".join(parts)
    return f"{low} to {high} seeds per cell"


def coverage(cfg, runs: list[tuple[str, str, int]], methods: list[str] | None = None) -> str:
    """'profile 'cpu': all 10 runs' or '... 7 of its 10 runs (missing ones: results/cpu/runs.md)'.

    `methods` narrows the profile's runs to those methods (e.g. the member methods a figure shows).
    """
    total = len([run for run in cfg.runs() if methods is None or run[1] in methods])
    what = "runs" if methods is None else f"{', '.join(methods)} runs"
    if len(runs) == total:
        return f"profile '{cfg.profile}': all {total} {what}"
    return (f"profile '{cfg.profile}': {len(runs)} of its {total} {what} (the missing ones are listed in "
            f"results/{cfg.profile}/runs.md)")


def caption(cfg, runs: list[tuple[str, str, int]], seeds: str, *details: str) -> str:
    """The parenthesis every table caption ends with: which runs, how many seeds per cell, the budget."""
    return "; ".join([coverage(cfg, runs), seeds, f"{cfg.steps_caption()} training steps per run", *details, "the paper used 3 seeds"])


def _span(values: pd.Series) -> str:
    low, high = int(values.min()), int(values.max())
    return f"{low}" if low == high else f"{low} to {high}"


#: How `protocol_note` names the collection protocols recorded in the datasets.
PROTOCOL_NAMES = {"main": "main-text protocol (section 5)", "appendix": "appendix G protocol"}


def protocol_note(metrics: pd.DataFrame) -> str:
    """How the scored states were collected, read from the per-run metrics (the datasets' own record).

    params.yaml may ask for another protocol than the committed datasets were collected with (until
    they are collected again); a caption must describe the states it rests on.
    """
    rows = metrics[metrics["ood_set"] == "perturbed"].drop_duplicates(["env", "method", "seed"])
    if rows.empty or not {"protocol", "n_ood", "n_ood_clusters", "n_id", "n_id_clusters"} <= set(rows.columns):
        return "collection protocol not recorded"
    parts = []
    for (name, actions), g in rows.groupby(["protocol", rows.get("actions", "actions unknown")], sort=False):
        parts.append(f"{PROTOCOL_NAMES.get(name, str(name))} with {actions} for {len(g)} run{'s' if len(g) != 1 else ''}: "
                     f"{_span(g['n_ood'])} OOD states from {_span(g['n_ood_clusters'])} configurations and "
                     f"{_span(g['n_id'])} held-out ID states from {_span(g['n_id_clusters'])} episodes per run")
    return "states as collected: " + "; ".join(parts)
