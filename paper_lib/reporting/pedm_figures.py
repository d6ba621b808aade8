"""Notebook 14's figures: each scorer per PEDM kind and severity, one panel per (env, severity), drawn with seaborn.

The same grid serves the AUROC, the time-matched AUROC and the detection delay (`kind_figure`): x = PEDM's kinds,
hue = scorer, a bar at the mean over the env's runs (every method and seed that has the scorer), a dot per run. The
clock (the step index as a score) is drawn as a scorer: the AUROC that knowing only the time gets; it has no delay.
`plots.save_figure` makes its text legible at the size the site shows it (`plots.legible`).
"""

from __future__ import annotations

import pandas as pd
import seaborn as sns
from matplotlib.figure import Figure

from paper_lib.common.frames import require_columns
from paper_lib.reporting.pedm_table import MEAN_KIND, SEVERITY_ORDER, scorer_order
from paper_lib.reporting.plots import _grid_figure, _legend_beside_grid, seeded_jitter

#: The quantities a figure shows: column, axis label, a reference line (chance for AUROC) and y limits.
QUANTITIES = {"auroc": ("AUROC (pooled per step)", 0.5, (0.0, 1.0)),
              "auroc_time_matched": ("AUROC (time-matched)", 0.5, (0.0, 1.0)),
              "delay_median": ("median delay (steps)", None, None)}


def kind_figure(runs: pd.DataFrame, value: str = "auroc") -> Figure:
    """`value` (a key of QUANTITIES) per kind and scorer, one panel per (env, severity); `runs` is `pedm_table`'s
    long form (its kind ``mean`` rows are left out: the kinds themselves are shown)."""
    if value not in QUANTITIES:
        raise ValueError(f"kind_figure draws one of {list(QUANTITIES)}, got {value!r}")
    require_columns(runs, ["env", "method", "seed", "scorer", "kind", "severity", value], "kind_figure")
    data = runs[runs["kind"] != MEAN_KIND].dropna(subset=[value])
    if data.empty:
        raise ValueError(f"kind_figure: no run has a {value} for any kind; nothing to draw")
    label, reference, limits = QUANTITIES[value]
    envs = list(pd.unique(data["env"]))
    severities = [s for s in SEVERITY_ORDER if s in set(data["severity"])]
    fig, axes = _grid_figure(len(envs) * len(severities), max_columns=len(severities))
    kinds, scorers = list(pd.unique(data["kind"])), scorer_order(data["scorer"])
    for ax, (env, severity) in zip(axes, [(e, s) for e in envs for s in severities]):
        panel = data[(data["env"] == env) & (data["severity"] == severity)]
        if panel.empty:  # e.g. a delay where no run flagged any minor perturbation
            ax.set(title=f"{env}, {severity}", xlabel="", ylabel=label)
            ax.text(0.5, 0.5, f"no run has a\n{label}", ha="center", va="center", transform=ax.transAxes)
            ax.set_xticks([])
            ax.set_yticks([])  # no scale to read: a bare 0-1 axis would suggest values of 0
            continue
        sns.barplot(data=panel, x="kind", y=value, hue="scorer", order=kinds, hue_order=scorers, errorbar=None,
                    alpha=0.5, ax=ax)
        with seeded_jitter():
            sns.stripplot(data=panel, x="kind", y=value, hue="scorer", order=kinds, hue_order=scorers, dodge=True,
                          size=3, legend=False, ax=ax)
        if reference is not None:
            ax.axhline(reference, color="black", linestyle="--", linewidth=0.8)
        ax.set(title=f"{env}, {severity}", xlabel="", ylabel=label)
        if limits is not None:
            ax.set_ylim(*limits)
        ax.tick_params(axis="x", labelrotation=30)
    _legend_beside_grid(fig, axes, title="scorer")
    return fig
