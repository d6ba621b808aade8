"""Checks on the DataFrames that tables and plots receive."""

from __future__ import annotations

import pandas as pd


def require_columns(df: pd.DataFrame, columns: list[str], where: str) -> None:
    """Raise one ValueError naming every missing column (and the ones that exist), or an empty frame."""
    if not isinstance(df, pd.DataFrame):
        raise ValueError(f"{where}: expected a pandas DataFrame, got {type(df).__name__}.")
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{where}: missing column(s) {missing}; the frame has {list(df.columns)}.")
    if df.empty:
        raise ValueError(f"{where}: the DataFrame is empty; there is nothing to show.")
