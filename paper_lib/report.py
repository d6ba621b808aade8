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
    """Rows: method x inference x action mode; columns: env; cells 'mean ± std'."""
    df = summary.assign(actions=np.where(summary["deterministic"], "deterministic", "sampled"),
                        cell=[f"{m:.1f} {PLUS_MINUS} {s:.1f}" for m, s in zip(summary["mean"], summary["std"])])
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
