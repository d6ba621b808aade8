"""The study's figures: reward-vs-AUROC scatters with each method's Pareto front (fig:scatter_mujoco,
fig:scatter_other_algs), the ablations of appendix C.1 and the scaling runs of appendix E.

Like `paper_lib.reporting.plots`, figures are built on an Agg canvas without pyplot; save them with
`paper_lib.reporting.plots.save_figure`. Every method keeps one colour in every figure.
"""

from __future__ import annotations

import pandas as pd
import seaborn as sns
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from paper_lib.common.frames import require_columns
from paper_lib.methods.networks import METHODS

PALETTE = dict(zip(METHODS, sns.color_palette("tab10", len(METHODS))))
PANEL = (4.0, 3.3)


def _figure(n_rows: int, n_cols: int, legend_width: float = 1.7, sharey: bool = False) -> tuple[Figure, list]:
    fig = Figure(figsize=(PANEL[0] * n_cols + legend_width, PANEL[1] * n_rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_rows, n_cols, squeeze=False, sharey=sharey)
    return fig, [ax for row in axes for ax in row]


def _legend_outside(fig: Figure, axes: list, title: str) -> None:
    handles, labels = [], []
    for ax in axes:
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(h)
                labels.append(label)
        if ax.get_legend() is not None:
            ax.get_legend().remove()
    if handles:
        fig.legend(handles, labels, title=title, loc="outside right upper", frameon=False)


def _methods(df: pd.DataFrame) -> list[str]:
    present = set(df["method"])
    return [m for m in METHODS if m in present]


def front_scatter(df: pd.DataFrame, panel: str = "env", max_columns: int = 2) -> Figure:
    """Reward vs AUROC of every trial, one panel per value of `panel`; each method's Pareto front joined and ringed.

    Expects COMPLETE trials with columns reward, auroc, method, is_pareto and `panel`. Panels wrap after
    `max_columns`: four envs in one row made a 17-inch strip that the results site showed 190 px high, its text
    at 8 px (issue 68); two rows of two show at half size, legible.
    """
    require_columns(df, ["reward", "auroc", "method", "is_pareto", panel], "front_scatter")
    values = list(pd.unique(df[panel]))
    n_cols = max(1, min(len(values), max_columns))
    fig, axes = _figure(-(-max(1, len(values)) // n_cols), n_cols)
    for ax in axes[len(values):]:
        fig.delaxes(ax)
    axes = axes[: len(values)]
    for ax, value in zip(axes, values):
        sub = df[df[panel] == value]
        for method in _methods(sub):
            trials = sub[sub["method"] == method]
            colour = PALETTE[method]
            ax.scatter(trials["reward"], trials["auroc"], s=16, alpha=0.45, color=colour, linewidths=0, label=method)
            front = trials[trials["is_pareto"]].sort_values("reward")
            ax.plot(front["reward"], front["auroc"], color=colour, linewidth=1.2, drawstyle="steps-pre")
            ax.scatter(front["reward"], front["auroc"], s=46, color=colour, edgecolors="black", linewidths=1.0)
        ax.set(title=str(value), xlabel="evaluation reward", ylabel="noise OOD AUROC")
    _legend_outside(fig, axes, "method (ringed: Pareto front)")
    return fig


def ablation_figure(rows: pd.DataFrame, axis: str, value: str, ylabel: str) -> Figure:
    """`value` against `axis` (k or p): all envs pooled per method, then one panel per method split by env.

    Mean over trials with a ±1 std band; expects columns method, env, `axis`, `value`.
    """
    require_columns(rows, ["method", "env", axis, value], "ablation_figure")
    methods = _methods(rows)
    fig, axes = _figure(1, 1 + len(methods), legend_width=2.2, sharey=True)
    sns.lineplot(data=rows, x=axis, y=value, hue="method", palette=PALETTE, hue_order=methods, marker="o",
                 errorbar="sd", ax=axes[0])
    axes[0].set(title="all envs", xlabel=axis, ylabel=ylabel)
    envs = list(pd.unique(rows["env"]))
    env_palette = dict(zip(envs, sns.color_palette("dark", len(envs))))
    for ax, method in zip(axes[1:], methods):
        sns.lineplot(data=rows[rows["method"] == method], x=axis, y=value, hue="env", palette=env_palette,
                     hue_order=envs, marker="o", errorbar="sd", ax=ax)
        ax.set(title=f"{method} by env", xlabel=axis, ylabel=ylabel)
    _legend_outside(fig, axes, "method / env")
    return fig


def scaling_curves(curves: pd.DataFrame) -> Figure:
    """Training reward over steps: one row per env, one panel per method, one line per hidden width."""
    require_columns(curves, ["env", "method", "width", "timesteps", "reward"], "scaling_curves")
    envs, methods = list(pd.unique(curves["env"])), _methods(curves)
    fig, axes = _figure(len(envs), len(methods), legend_width=1.2)
    widths = sorted(curves["width"].unique())
    width_palette = dict(zip(widths, sns.color_palette("viridis", len(widths))))
    for r, env in enumerate(envs):
        for c, method in enumerate(methods):
            ax = axes[r * len(methods) + c]
            sub = curves[(curves["env"] == env) & (curves["method"] == method)]
            sns.lineplot(data=sub, x="timesteps", y="reward", hue="width", palette=width_palette, hue_order=widths,
                         errorbar="sd", ax=ax)
            ax.set(title=f"{env}: {method}", xlabel="timesteps", ylabel="training episode reward")
    _legend_outside(fig, axes, "hidden units")
    return fig


def scaling_final(final: pd.DataFrame) -> Figure:
    """Final evaluation reward per hidden width, one panel per env, one colour per method (±1 std)."""
    require_columns(final, ["env", "method", "width", "reward"], "scaling_final")
    envs = list(pd.unique(final["env"]))
    fig, axes = _figure(1, len(envs))
    for ax, env in zip(axes, envs):
        sub = final[final["env"] == env]
        methods = _methods(sub)  # seaborn divides the dodge among the methods: one method is not dodged
        sns.pointplot(data=sub, x="width", y="reward", hue="method", palette=PALETTE, hue_order=methods,
                      errorbar="sd", dodge=0.3 if len(methods) > 1 else False, ax=ax)
        ax.set(title=str(env), xlabel="hidden units per layer", ylabel="final evaluation reward")
    _legend_outside(fig, axes, "method")
    return fig
