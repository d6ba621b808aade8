"""Tables and figures of the guard experiment, from GuardRun frames tagged with env, method and seed."""

from __future__ import annotations

import numpy as np
import pandas as pd
import seaborn as sns
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from paper_lib.common.frames import require_columns
from paper_lib.guard.conformal import false_alarm_bound
from paper_lib.reporting.plots import FIGURE_SEED

KEYS = ["env", "method", "score", "guard"]
GUARD_ORDER = ["state", "window", "cusum"]


def _ordered(df: pd.DataFrame, methods: list[str]) -> pd.DataFrame:
    out = df.copy()
    out["method"] = pd.Categorical(out["method"], categories=[m for m in methods if m in set(out["method"])],
                                   ordered=True)
    out["guard"] = pd.Categorical(out["guard"], categories=GUARD_ORDER, ordered=True)
    return out.sort_values(["env", "method", "guard", "score"]).reset_index(drop=True)


def detection_table(episodes: pd.DataFrame, methods: list[str]) -> pd.DataFrame:
    """Per env, method, score and guard: false alarms on ID episodes and detection of the changes.

    - ``id_alarms_per_1000_steps``: flagged ID steps per 1000 (pooled over steps, so long episodes weigh more);
    - ``id_episodes_with_alarm``: share of ID test episodes with any alarm;
    - ``id_false_alarm_rate``: what the guard bounds by alpha: for the state guard the chance that a state at a
      uniformly random step of a random ID episode is flagged (mean over episodes of the flagged share, as the
      calibration states were drawn), for the window and CUSUM guards ``id_episodes_with_alarm``;
    - ``expected_rate``: that rate's expectation over calibration sets, (n + 1 - k) / (n + 1);
    - ``detected``: share of perturbed episodes with an alarm after the change;
    - ``median_delay``: median steps from the change to the first alarm, over detected episodes;
    - ``alarm_before_change``: share of perturbed episodes flagged at or before the change.

    Perturbed episodes that ended before their change (a robot that fell) are left out.
    """
    require_columns(episodes, KEYS + ["episode_kind", "steps", "flagged_steps", "any_alarm", "delay",
                                      "alarm_before_change", "reached_change", "alpha", "n_calibration"],
                    "detection_table")
    confidence = episodes["confidence"] if "confidence" in episodes else pd.Series(np.nan, index=episodes.index)
    episodes = episodes.assign(confidence=confidence.astype(float))
    rows = []
    for key, group in episodes.groupby(KEYS, sort=False):
        ident = group[group.episode_kind == "id"]
        pert = group[(group.episode_kind == "perturbed") & group.reached_change.astype(bool)]
        delays = pert["delay"].dropna()
        alpha, n = float(group["alpha"].iloc[0]), int(group["n_calibration"].iloc[0])
        confidence = float(group["confidence"].iloc[0])
        with_alarm = ident["any_alarm"].mean() if len(ident) else np.nan
        state_rate = (ident["flagged_steps"] / ident["steps"].clip(lower=1)).mean() if len(ident) else np.nan
        rows.append(dict(zip(KEYS, key), alpha=alpha, confidence=confidence, n_calibration=n,
                         expected_rate=false_alarm_bound(n, alpha, None if np.isnan(confidence) else confidence),
                         id_episodes=len(ident),
                         id_false_alarm_rate=state_rate if key[3] == "state" else with_alarm,
                         id_alarms_per_1000_steps=1000 * ident["flagged_steps"].sum() / max(ident["steps"].sum(), 1),
                         id_episodes_with_alarm=with_alarm,
                         perturbed_episodes=len(pert), detected=delays.size / len(pert) if len(pert) else np.nan,
                         median_delay=delays.median() if delays.size else np.nan,
                         alarm_before_change=pert["alarm_before_change"].mean() if len(pert) else np.nan))
    return _ordered(pd.DataFrame(rows), methods)


def returns_table(returns: pd.DataFrame, methods: list[str]) -> pd.DataFrame:
    """Per env, method and fallback guard: mean return after the change with and without the zero-action fallback."""
    require_columns(returns, ["env", "method", "score", "guard", "post_change_return_without", "post_change_return_with",
                              "return_without", "return_with", "fallback_share_after_change", "reached_change"],
                    "returns_table")
    out = (returns[returns.reached_change.astype(bool)].groupby(KEYS, sort=False)
           .agg(episodes=("episode", "size"),
                post_change_return_without=("post_change_return_without", "mean"),
                post_change_return_with=("post_change_return_with", "mean"),
                return_without=("return_without", "mean"), return_with=("return_with", "mean"),
                fallback_share_after_change=("fallback_share_after_change", "mean"))
           .reset_index())
    out["post_change_difference"] = out["post_change_return_with"] - out["post_change_return_without"]
    return _ordered(out, methods)


def _figure(n_rows: int, n_cols: int, width: float, height: float) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=(width * n_cols + 1.8, height * n_rows), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots(n_rows, n_cols, squeeze=False)


def _one_legend(fig: Figure, axes: np.ndarray) -> None:
    """Panels share one hue: keep the fullest legend, outside the panels on the right."""
    best = max(axes.flat, key=lambda ax: len(ax.get_legend_handles_labels()[0]))
    handles, labels = best.get_legend_handles_labels()
    for ax in axes.flat:
        if ax.get_legend() is not None:
            ax.get_legend().remove()
    if handles:  # an axes legend outside the last panel of the first row: constrained layout makes room for it
        axes[0, -1].legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False,
                           fontsize="small", title="method")


def _bar_height(table: pd.DataFrame) -> float:
    return max(2.6, 0.16 * table["score"].nunique() * table["method"].nunique() + 0.8)


def false_alarm_figure(table: pd.DataFrame) -> Figure:
    """Per env and guard kind: the ID false-alarm rate each guard bounds (a random state flagged for the state
    guard, an episode with any alarm for the window and CUSUM guards) against alpha (dashed line)."""
    require_columns(table, KEYS + ["alpha", "id_false_alarm_rate"], "false_alarm_figure")
    envs, methods = list(dict.fromkeys(table["env"])), [str(m) for m in dict.fromkeys(table["method"])]
    fig, axes = _figure(len(envs), 3, 3.6, _bar_height(table))
    panels = (("state", "id_false_alarm_rate", 1.0, "ID states flagged"),
              ("window", "id_false_alarm_rate", 1.0, "ID episodes with an alarm"),
              ("cusum", "id_false_alarm_rate", 1.0, "ID episodes with an alarm"))
    for i, env in enumerate(envs):
        sub = table[table.env == env].assign(method=lambda d: d["method"].astype(str))
        alpha = float(sub["alpha"].iloc[0])
        scores = list(dict.fromkeys(sub["score"]))  # one row order for the three panels, named once on the left
        for j, (guard, column, scale, label) in enumerate(panels):
            ax = axes[i, j]
            sns.barplot(sub[sub.guard == guard], y="score", x=column, hue="method", hue_order=methods, order=scores,
                        ax=ax, orient="h", seed=FIGURE_SEED)
            ax.axvline(scale * alpha, color="k", ls="--", lw=1)
            ax.set(title=f"{env}: {guard} guard", ylabel="", xlabel=label)
            ax.tick_params(axis="y", labelsize="small", labelleft=j == 0)
    _one_legend(fig, axes)
    return fig


def delay_figure(episodes: pd.DataFrame, guard: str = "window") -> Figure:
    """Detection delays (steps from the change to the first alarm) of one guard kind, detected episodes only."""
    require_columns(episodes, KEYS + ["episode_kind", "delay"], "delay_figure")
    data = episodes[(episodes.guard == guard) & (episodes.episode_kind == "perturbed")].dropna(subset=["delay"])
    envs, methods = list(dict.fromkeys(episodes["env"])), [str(m) for m in dict.fromkeys(episodes["method"])]
    fig, axes = _figure(1, len(envs), 4.6, _bar_height(episodes))
    for j, env in enumerate(envs):
        ax = axes[0, j]
        sub = data[data.env == env].assign(method=lambda d: d["method"].astype(str))
        if len(sub):
            sns.boxplot(sub, y="score", x="delay", hue="method", hue_order=methods, ax=ax, orient="h", fliersize=2,
                        linewidth=0.8)
        ax.set(title=f"{env}: {guard} guard", ylabel="", xlabel="delay (steps after the change)")
        ax.tick_params(axis="y", labelsize="small")
    _one_legend(fig, axes)
    return fig


def trace_figure(traces: pd.DataFrame) -> Figure:
    """The first perturbed episode of each run: the window statistic over its threshold, change marked."""
    require_columns(traces, ["env", "method", "score", "step", "statistic", "threshold", "change_step"], "trace_figure")
    data = traces.assign(ratio=lambda d: d["statistic"] / d["threshold"].where(d["threshold"] > 0),
                         method=lambda d: d["method"].astype(str))
    data = data[np.isfinite(data["ratio"])]
    envs, scores = list(dict.fromkeys(traces["env"])), list(dict.fromkeys(traces["score"]))
    methods = [str(m) for m in dict.fromkeys(traces["method"])]
    fig, axes = _figure(len(scores), len(envs), 4.6, 3.0)
    for i, score in enumerate(scores):
        for j, env in enumerate(envs):
            ax = axes[i, j]
            sub = data[(data.env == env) & (data.score == score)]
            if len(sub):
                sns.lineplot(sub, x="step", y="ratio", hue="method", hue_order=methods, ax=ax, lw=1, seed=FIGURE_SEED)
                ax.axvline(sub["change_step"].iloc[0], color="r", ls=":", lw=1)
            ax.axhline(1.0, color="k", ls="--", lw=1)
            ax.set(title=f"{env}: {score}", ylabel="window statistic / threshold")
    _one_legend(fig, axes)
    return fig
