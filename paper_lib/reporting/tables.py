"""Result tables in three formats: CSV (for code), Markdown (for the README) and LaTeX (for the paper).

All three are written atomically from the same DataFrame, so they never disagree
and a crash never leaves a stale or half-written table.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from paper_lib.common.frames import require_columns
from paper_lib.common.io import write_text_atomic

PLUS_MINUS = "\u00b1"  # "±"
#: The mark of a table cell whose interval rests on one training seed, and the footnote that says what that means.
ONE_SEED_MARK = "\u00b9"  # "¹"
ONE_SEED_NOTE = (f"{ONE_SEED_MARK} one training seed: the interval covers that one run's episodes or states, not the "
                 "spread between training runs (a hint, not a finding)")
#: The Monte Carlo standard error at which an estimate's last printed decimal is sampling noise (issue 36): an
#: interval cell whose MC standard error is at least MC_SE_LIMIT shows one decimal fewer (0.005 with "%.3f").
MC_SE_LIMIT = 0.005
#: A column named `<column>` + MC_SE_SUFFIX holds `<column>`'s MC standard error: the CSV keeps it, Markdown and
#: LaTeX show `<column>` to the digits it supports and leave the error column out.
MC_SE_SUFFIX = "_mc_se"
MC_DIGITS_NOTE = ("Numbers printed with one decimal fewer have a Monte Carlo standard error of "
                  f"{MC_SE_LIMIT} or more (MC Dropout/DropConnect and the feature detectors on their members: the "
                  "AUROC's std over the scoring seeds, ddof=1, / sqrt(scoring seeds x training seeds); a difference: "
                  "both sides' errors combined): their next digit would be the sampling noise of the uncertainty "
                  "estimate, not a property of the agent")


#: Significant digits a CSV keeps: far more than any table prints, yet fewer than a double's ~16, so that the last
#: bits another CPU changes (another SIMD summation order or libm, ~1e-16 relative) do not reach a rebuild's bytes.
CSV_SIGNIFICANT_DIGITS = 12


def _significant(values: pd.Series) -> np.ndarray:
    return np.array([float(f"{v:.{CSV_SIGNIFICANT_DIGITS}g}") for v in values], dtype=float)


def csv_text(df: pd.DataFrame) -> str:
    """``df`` as CSV text (no index), its floats rounded to CSV_SIGNIFICANT_DIGITS: the same bytes on any CPU."""
    out = df.copy()
    for i in range(out.shape[1]):
        if pd.api.types.is_float_dtype(out.iloc[:, i]):
            out.isetitem(i, _significant(out.iloc[:, i]))
    return out.to_csv(index=False, lineterminator="\n")


def _stem_path(stem: str | os.PathLike[str], suffix: str) -> Path:
    """Append ``suffix`` to the stem (not with_suffix: stems like 'roc.value' keep their dot)."""
    return Path(f"{os.fspath(stem)}{suffix}")


def _has_default_index(df: pd.DataFrame) -> bool:
    """A plain 0..n-1 index carries no information and is left out of the written tables."""
    return isinstance(df.index, pd.RangeIndex) and df.index.name is None and df.index.start == 0 and df.index.step == 1


def _format_cells(df: pd.DataFrame, float_format: str) -> pd.DataFrame:
    """Format float cells with ``float_format`` ("%.3f"); other cells become str(cell)."""

    def fmt(x: object) -> str:
        if isinstance(x, (float, np.floating)):
            return "NaN" if np.isnan(x) else float_format % x
        return str(x)

    return df.map(fmt)


def _markdown_table(df: pd.DataFrame, right: list[bool]) -> str:
    """Plain pipe table, used when tabulate (pandas' Markdown backend) is not installed."""
    header = [str(c) for c in df.columns]
    rule = ["---:" if r else ":---" for r in right]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(rule) + "|"]
    lines += ["| " + " | ".join(str(x) for x in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines)


def to_markdown(df: pd.DataFrame, right: list[bool]) -> str:
    """Markdown table of an all-string frame; ``right[i]`` right-aligns column i (numbers).

    Uses tabulate (pandas' backend) when installed and our own writer otherwise.
    """

    def cell(x: object) -> str:
        return str(x).replace("|", "\\|").replace("\n", " ")

    safe = df.map(cell).rename(columns=cell)
    try:
        import tabulate  # noqa: F401  (only probing that pandas' backend exists)
    except ImportError:
        return _markdown_table(safe, right)
    # disable_numparse: cells are already formatted; tabulate must not re-round them.
    colalign = ["right" if r else "left" for r in right]
    return safe.to_markdown(index=False, disable_numparse=True, colalign=colalign)


def _latex_escape(text: str) -> str:
    """Escape LaTeX special characters so plain-text captions and cells compile."""
    repl = {
        "\\": r"\textbackslash{}",
        "&": r"\&",
        "%": r"\%",
        "$": r"\$",
        "#": r"\#",
        "_": r"\_",
        "{": r"\{",
        "}": r"\}",
        "~": r"\textasciitilde{}",
        "^": r"\textasciicircum{}",
        "|": r"\textbar{}",
    }
    return "".join(repl.get(ch, ch) for ch in text)


def to_latex(df: pd.DataFrame, caption: str, right: list[bool], label: str | None = None) -> str:
    """Booktabs LaTeX table (needs \\usepackage{booktabs}); cells, headers and caption are escaped."""

    def tex(x: object) -> str:
        return _latex_escape(str(x)).replace(PLUS_MINUS, r"$\pm$").replace(ONE_SEED_MARK, r"$^{1}$")

    safe = df.map(tex).rename(columns=tex)
    styler = safe.style.hide(axis="index")
    column_format = "".join("r" if r else "l" for r in right)
    return styler.to_latex(
        hrules=True, caption=tex(caption), label=label, position_float="centering", column_format=column_format
    )


def mc_standard_error(df: pd.DataFrame, estimate: str, seeds: str | None = "n_seeds") -> pd.Series | None:
    """The Monte Carlo standard error of each row's ``estimate``, or None where the frame does not carry its MC spread.

    A stochastic method's (MC Dropout / DropConnect) run AUROC is the mean over ``n_scoring_seeds`` scoring seeds,
    and a cell the mean of ``seeds`` runs; the frame carries ``<estimate>_scoring_std`` (`measure_metrics`: the
    population std, ddof=0, over a run's scoring seeds; `summarize_seeds`: its mean over the cell's runs). With
    s that std and m, n the counts, the sample std over scoring seeds is s*sqrt(m/(m-1)), so a run's MC standard
    error is s/sqrt(m-1) and the cell's, its runs' errors being independent, s/sqrt((m-1)*n). (The mean of the
    runs' s stands in for their root mean square, a little lower where runs' spreads differ.) One scoring seed
    with no spread (a deterministic method) has error 0; one scoring seed of a stochastic method has an unknown
    error (NaN), and its cell keeps its digits. A frame that carries the error itself, as ``<estimate>_mc_se``
    (`paper_tables`' difference tables, from each run's spread: `statistics.mc_standard_error`), gives it as is.
    """
    if f"{estimate}{MC_SE_SUFFIX}" in df.columns:
        return pd.to_numeric(df[f"{estimate}{MC_SE_SUFFIX}"], errors="coerce").astype(float)
    spread = f"{estimate}_scoring_std"
    if spread not in df.columns or "n_scoring_seeds" not in df.columns:
        return None
    std = pd.to_numeric(df[spread], errors="coerce").astype(float)
    m = pd.to_numeric(df["n_scoring_seeds"], errors="coerce").astype(float)
    n = pd.to_numeric(df[seeds], errors="coerce").astype(float) if seeds and seeds in df.columns else 1.0
    se = std / np.sqrt((m - 1).where(m > 1) * n)
    return se.where(m > 1, np.where(std == 0, 0.0, np.nan))


def _decimals(float_format: str) -> int:
    match = re.fullmatch(r"%\.(\d+)f", float_format)
    if match is None:
        raise ValueError(f"an interval cell with a Monte Carlo standard error needs a fixed-point format such as "
                         f"'%.3f' (it drops decimals the MC noise does not support), got {float_format!r}.")
    return int(match.group(1))


def mc_decimals(se: pd.Series, float_format: str = "%.3f", limit: float = MC_SE_LIMIT) -> pd.Series:
    """Decimals each cell supports: ``float_format``'s, one fewer for each factor of 10 its MC standard error reaches
    ``limit`` (scaled to that decimal): SE 0.006 with "%.3f" -> 2, 0.004 -> 3, 0.06 -> 1; NaN keeps them all."""
    digits = _decimals(float_format)
    se = pd.to_numeric(pd.Series(se), errors="coerce").astype(float)
    out = []
    for e in se:
        d = digits
        while d > 0 and not np.isnan(e) and e >= limit * 10.0 ** (digits - d):
            d -= 1
        out.append(d)
    return pd.Series(out, index=se.index, dtype=int)


def interval_cells(df: pd.DataFrame, estimate: str, low: str, high: str, seeds: str | None = "n_seeds",
                   float_format: str = "%.3f", mc_se: str | None = None) -> pd.Series:
    """One shown cell per row: 'estimate [low, high]', marked ONE_SEED_MARK where column ``seeds`` is 1.

    A reader who looks at one cell must see there that its interval rests on one training seed,
    not only in a caption or a column beside it; an interval that does not exist (NaN) is left out.
    ``mc_se`` names a column with the estimate's Monte Carlo standard error (`mc_standard_error`):
    a cell where it reaches MC_SE_LIMIT is printed with one decimal fewer (`mc_decimals`), so it
    shows no digit the scoring seeds' sampling noise does not support.
    """
    missing = [c for c in (estimate, low, high, seeds, mc_se) if c is not None and c not in df.columns]
    if missing:  # an empty table (no rows yet) is fine: it shows its header
        raise ValueError(f"interval_cells: missing column(s) {missing}; the frame has {list(df.columns)}.")
    decimals = (mc_decimals(df[mc_se], float_format) if mc_se is not None else pd.Series(index=df.index, dtype=int))

    def number(x: float, d: int | None) -> str:
        return "NaN" if pd.isna(x) else (float_format % x if d is None else f"{x:.{d}f}")

    cells = []
    for e, lo, hi, d in zip(df[estimate], df[low], df[high], decimals.reindex(df.index).tolist()):
        d = None if pd.isna(d) else int(d)
        interval = "" if pd.isna(lo) or pd.isna(hi) else f" [{number(lo, d)}, {number(hi, d)}]"
        cells.append(number(e, d) + interval)
    one_seed = (df[seeds] == 1).to_numpy() if seeds else np.zeros(len(df), dtype=bool)
    return pd.Series([c + ONE_SEED_MARK if one else c for c, one in zip(cells, one_seed)], index=df.index,
                     dtype=object)


def _with_intervals(flat: pd.DataFrame, intervals: dict[str, tuple[str, str]], seeds: str | None,
                    float_format: str) -> tuple[pd.DataFrame, bool, bool]:
    """``flat`` with each estimate column shown as its interval cell ('<estimate> [95% CI]') and its bounds dropped;
    whether any cell carries the one-seed mark; and whether any cell shows fewer decimals for its MC noise."""
    shown = flat.copy()
    marked = shortened = False
    for estimate, (low, high) in intervals.items():
        se = mc_standard_error(flat, estimate, seeds)
        if se is None:
            cells = interval_cells(flat, estimate, low, high, seeds, float_format)
        else:
            cells = interval_cells(flat.assign(_mc_se=se), estimate, low, high, seeds, float_format, mc_se="_mc_se")
            shortened |= bool((mc_decimals(se, float_format) < _decimals(float_format)).any())
        marked |= bool(cells.str.endswith(ONE_SEED_MARK).any())
        shown[estimate] = cells
        shown = shown.drop(columns=[low, high]).rename(columns={estimate: f"{estimate} [95% CI]"})
    return shown, marked, shortened


def _mc_plain_columns(display: pd.DataFrame, flat: pd.DataFrame, float_format: str) -> tuple[pd.DataFrame, bool]:
    """``display`` without its MC error columns, each plain number column that has one printed to the decimals its
    error supports (`mc_decimals`); and whether any cell lost a decimal."""
    errors = [c for c in display.columns if c.endswith(MC_SE_SUFFIX)]
    shown, shortened = display.drop(columns=errors), False
    for column in (c[: -len(MC_SE_SUFFIX)] for c in errors):
        if column not in shown.columns or not pd.api.types.is_float_dtype(shown[column]):
            continue  # an interval column is already a cell (`_with_intervals` used the error)
        decimals = mc_decimals(flat[f"{column}{MC_SE_SUFFIX}"], float_format)
        shortened |= bool((decimals < _decimals(float_format)).any())
        shown[column] = ["NaN" if pd.isna(x) else f"{x:.{d}f}" for x, d in zip(shown[column], decimals)]
    return shown, shortened


def _with_cell_text(shown: pd.DataFrame, df: pd.DataFrame, cell_text: pd.DataFrame) -> pd.DataFrame:
    """``shown`` with each cell where ``cell_text`` holds a non-empty string replaced by that string."""
    if not (_has_default_index(df) and cell_text.shape == df.shape and list(cell_text.columns) == list(df.columns)):
        raise ValueError(f"save_table: cell_text must have the table's shape {df.shape} and columns {list(df.columns)} "
                         f"with a default index, got shape {cell_text.shape} and columns {list(cell_text.columns)}.")
    if list(shown.columns) != [str(c) for c in df.columns]:
        raise ValueError("save_table: cell_text cannot be combined with intervals (they reshape the shown columns).")
    out = shown.copy()
    text = cell_text.to_numpy(dtype=object)
    for i, j in zip(*np.nonzero([[isinstance(x, str) and x != "" for x in row] for row in text])):
        out.iat[i, j] = text[i, j]
    return out


def save_table(
    df: pd.DataFrame,
    stem: str | os.PathLike[str],
    caption: str,
    float_format: str = "%.3f",
    label: str | None = None,
    intervals: dict[str, tuple[str, str]] | None = None,
    seeds: str | None = "n_seeds",
    cell_text: pd.DataFrame | None = None,
) -> dict[str, Path]:
    """Write ``stem``.csv, .md and .tex atomically; return their paths keyed by format.

    The CSV keeps 12 significant digits (it is what code reads back; `csv_text`); Markdown and
    LaTeX show floats with ``float_format``. ``caption`` is plain text: it is the
    first line of the .md and is LaTeX-escaped into the .tex caption. A non-default
    index is written as leading column(s). ``intervals`` ({estimate: (low, high)}) shows
    each estimate with its interval in one Markdown/LaTeX cell, marked where column
    ``seeds`` is 1 (`interval_cells`), and then adds ONE_SEED_NOTE to the caption; the
    CSV keeps the three columns apart. An estimate whose frame carries its Monte Carlo spread
    (``<estimate>_scoring_std`` and ``n_scoring_seeds``, as `summarize_seeds` gives for auroc) is shown
    to the decimals that noise supports (`mc_standard_error`, `mc_decimals`), and where a cell drops
    one, MC_DIGITS_NOTE joins the caption. ``cell_text`` (a frame of ``df``'s shape, same columns, default
    index) gives text that Markdown and LaTeX show in place of a cell where it is a non-empty string ('not
    scored'); the CSV keeps ``df``'s value (NaN, a number), so code reading it still gets numbers.
    """
    if not isinstance(df, pd.DataFrame) or df.shape[1] == 0:
        raise ValueError(f"save_table: expected a DataFrame with at least one column, got {type(df).__name__}.")
    if not isinstance(caption, str) or not caption.strip():
        raise ValueError("save_table: caption must be a non-empty string; every table states what it shows.")
    try:
        float_format % 1.0
    except (TypeError, ValueError):
        raise ValueError(
            f"save_table: float_format must be a %-style format such as '%.3f', got {float_format!r}."
        ) from None
    flat = df.copy() if _has_default_index(df) else df.reset_index()
    flat.columns = [str(c) for c in flat.columns]
    display, marked, shortened = (_with_intervals(flat, intervals, seeds, float_format) if intervals
                                  else (flat, False, False))
    display, plain_shortened = _mc_plain_columns(display, flat, float_format)
    shortened |= plain_shortened
    if marked:
        caption = f"{caption.strip()} {ONE_SEED_NOTE}."
    if shortened:
        caption = f"{caption.strip()} {MC_DIGITS_NOTE}."
    shown = _format_cells(display, float_format)
    if cell_text is not None:
        shown = _with_cell_text(shown, df, cell_text)
    right = [pd.api.types.is_numeric_dtype(flat[c]) and not pd.api.types.is_bool_dtype(flat[c]) if c in flat else True
             for c in display.columns]
    paths = {fmt: _stem_path(stem, f".{fmt}") for fmt in ("csv", "md", "tex")}
    write_text_atomic(paths["csv"], csv_text(flat))
    write_text_atomic(paths["md"], f"{caption.strip()}\n\n{to_markdown(shown, right)}\n")
    write_text_atomic(paths["tex"], to_latex(shown, caption.strip(), right, label))
    return paths


def mean_std_values(df: pd.DataFrame, index: str, columns: str, value: str) -> pd.DataFrame:
    """Mean, sample std (ddof=1) and count of ``value`` over the remaining rows (seeds).

    Returns a frame indexed by ``index`` with MultiIndex columns (stat, ``columns``),
    stat in {"mean", "std", "n"}; std is NaN where only one seed exists.
    """
    require_columns(df, [index, columns, value], "mean_std_values")
    vals = pd.to_numeric(df[value], errors="coerce")
    if vals.isna().any():
        bad = df.loc[vals.isna(), [index, columns, value]].head(3).to_dict("records")
        raise ValueError(
            f"mean_std_values: column {value!r} has missing or non-numeric values, e.g. {bad}; fix them first."
        )
    grouped = df.assign(**{value: vals}).groupby([index, columns], sort=False)[value]
    stats = grouped.agg(mean="mean", std="std", n="count")
    wide = stats.unstack(columns)
    wide.columns = wide.columns.set_names(["stat", columns])
    # groupby(sort=False)/unstack sorts the columns; restore first-appearance order.
    order = pd.unique(df[columns])
    return wide.reindex(columns=pd.MultiIndex.from_product([["mean", "std", "n"], order], names=["stat", columns]))


def mean_std_table(
    df: pd.DataFrame, index: str, columns: str, value: str, float_format: str = "%.1f"
) -> pd.DataFrame:
    """Table of "mean ± std" strings over seeds (rows ``index``, columns ``columns``).

    A cell with one seed shows the mean alone (no spread can be estimated); an
    empty combination shows "".
    """
    stats = mean_std_values(df, index, columns, value)
    out = pd.DataFrame(index=stats.index, columns=stats["mean"].columns, dtype=object)
    for col in out.columns:
        for row in out.index:
            m, s, n = stats.at[row, ("mean", col)], stats.at[row, ("std", col)], stats.at[row, ("n", col)]
            if pd.isna(n) or n == 0:
                out.at[row, col] = ""
            elif n == 1:
                out.at[row, col] = float_format % m
            else:
                out.at[row, col] = f"{float_format % m} {PLUS_MINUS} {float_format % s}"
    out.columns.name = columns
    return out
