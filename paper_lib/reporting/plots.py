"""Paper figures from tidy DataFrames, drawn with seaborn.

Figures are built as ``matplotlib.figure.Figure`` objects on an Agg canvas rather
than through pyplot: no global backend switch (notebooks keep their inline
backend and still display the returned figure), no GUI, and no figure registry
that leaks memory in long pipelines. ``save_figure`` writes PNG + PDF atomically
with the PDF creation date removed, and every random draw a figure makes is seeded
(``FIGURE_SEED``: seaborn's bootstrap intervals, ``seeded_jitter`` for strip plots),
so equal inputs give byte-identical files.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import matplotlib.pyplot as plt  # only for plt.close; figures are built without pyplot
import numpy as np
import pandas as pd
import seaborn as sns
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from paper_lib.common.frames import require_columns
from paper_lib.common.io import atomic_path
from paper_lib.reporting.display import DPI, min_font_pt

PANEL_SIZE = (4.0, 3.2)  # inches per panel
#: Seed of seaborn's bootstrap confidence intervals (its `seed=`) and of strip-plot jitter (`seeded_jitter`).
FIGURE_SEED = 0


@contextmanager
def seeded_jitter(seed: int = FIGURE_SEED) -> Iterator[None]:
    """Seed NumPy's global RNG for the plots drawn inside, then give the caller its state back.

    seaborn's stripplot jitters its dots with `np.random.uniform` and takes no seed, so without this a
    redrawn figure moves every dot and `make reproduce` rewrites the committed file each time.
    """
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def _new_figure(n_panels: int = 1, sharey: bool = True, legend_width: float = 0.0) -> tuple[Figure, list]:
    """A Figure on an Agg canvas with ``n_panels`` side-by-side axes (plus room for an outside legend)."""
    fig = Figure(figsize=(PANEL_SIZE[0] * n_panels + legend_width, PANEL_SIZE[1]), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, n_panels, sharey=sharey, squeeze=False)[0]
    return fig, list(axes)


def _grid_figure(n_panels: int, max_columns: int) -> tuple[Figure, list]:
    """Panels in rows of at most ``max_columns`` (unused cells hidden), so 8 envs stay readable."""
    n_columns = max(1, min(n_panels, max_columns))
    n_rows = -(-n_panels // n_columns)
    fig = Figure(figsize=(PANEL_SIZE[0] * n_columns, PANEL_SIZE[1] * n_rows), layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.subplots(n_rows, n_columns, squeeze=False).ravel()
    for ax in grid[n_panels:]:
        fig.delaxes(ax)
    return fig, list(grid[:n_panels])


def _legend_beside_grid(fig: Figure, axes: list, title: str | None = None) -> None:
    """One figure legend right of a panel grid (taken from the last panel that has one), not inside a cell."""
    legends = [ax for ax in axes if ax.get_legend() is not None]  # a panel with nothing to draw has none
    if not legends:
        return
    handles, labels = legends[-1].get_legend_handles_labels()
    for ax in legends:
        ax.get_legend().remove()
    fig.legend(handles, labels, title=title, loc="outside right upper", frameon=False)


def _keep_last_legend(axes: list, outside: bool = False) -> None:
    """Panels share hue/style, so one legend (on the last panel) is enough; ``outside`` keeps it off the data."""
    for ax in axes[:-1]:
        if ax.get_legend() is not None:
            ax.get_legend().remove()
    if outside and axes[-1].get_legend() is not None:
        sns.move_legend(axes[-1], "upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)


#: The PNG text field (tEXt) where `save_figure` records the smallest font size drawn, in points: with the PNG's width
#: and dpi it gives the size that text shows at on the site (`display.displayed_font_px`), read without redrawing.
SMALLEST_FONT_KEY = "Smallest font (pt)"


def legible(fig: Figure, dpi: float = DPI) -> float:
    """Raise every text of ``fig`` smaller than the site needs to ``display.min_font_pt``; return the smallest size.

    The site shows a figure at half its pixel width, capped by its column, so a wide multi-panel figure (a 16-inch
    ROC grid, a 21-inch strip) shows matplotlib's 10 pt at 9 px or less and 'x-small' at 5 px. Titles, labels,
    tick labels, legends and suptitles below the floor for this figure's width are drawn at the floor; larger
    text keeps its size. Where even the default size is below the floor (a strip over 14 inches wide), the figure
    grows taller by the same factor, so its panels keep their share of it. Constrained layout makes room when the
    figure is drawn; the suptitle is centred over the panels and wrapped to their width (`_fit_suptitle`), a panel
    title to its panel's, and x tick labels that now overlap turn upright (`_untangle_tick_labels`).
    """
    from matplotlib.text import Text

    import matplotlib as mpl

    floor = round(min_font_pt(fig.get_figwidth(), dpi), 2)
    grown = floor / mpl.rcParams["font.size"]
    if grown > 1:  # a figure so wide that even the default size is too small: taller by as much as its text grows
        fig.set_figheight(fig.get_figheight() * grown)
    fig.draw_without_rendering()  # tick labels exist only once the figure has been drawn
    for ax in fig.axes:
        for axis, labels in (("x", ax.get_xticklabels(which="both")), ("y", ax.get_yticklabels(which="both"))):
            if any(label.get_fontsize() < floor for label in labels):
                ax.tick_params(axis=axis, which="both", labelsize=floor)  # ticks made at the next draw too
    texts = [t for t in fig.findobj(Text) if t.get_text()]
    for text in texts:
        if text.get_fontsize() < floor:
            text.set_fontsize(floor)
    _fit_suptitle(fig)
    _untangle_tick_labels(fig)
    return min((t.get_fontsize() for t in texts if t.get_visible()), default=floor)


def _untangle_tick_labels(fig: Figure) -> None:
    """At their legible size, wrap a panel title wider than its panel, and turn a panel's x tick labels upright
    where neighbours overlap (long category names).

    A title then stays over its own panel; upright, a label takes its line height across, not its length.
    """
    fig.draw_without_rendering()
    for ax in fig.axes:
        title, spec = ax.title, ax.get_subplotspec()
        # the panel's cell of the grid, not the axes box: an image's axes shrink to its aspect, the cell does not
        span = spec.get_position(fig).width * fig.bbox.width if spec is not None else ax.get_window_extent().width
        wide = title.get_window_extent().width if title.get_text() else 0
        if wide > span > 0:
            title.set_text(_rewrapped(title.get_text(), span / wide))
    for ax in fig.axes:
        boxes = sorted((label.get_window_extent() for label in ax.get_xticklabels()
                        if label.get_visible() and label.get_text()), key=lambda box: box.x0)
        if any(left.x1 > right.x0 for left, right in zip(boxes, boxes[1:])):
            ax.tick_params(axis="x", labelrotation=90)


def _rewrapped(text: str, shrink: float) -> str:
    """`text` wrapped anew so its longest line is `shrink` (< 1) times as wide as now (widths by character count)."""
    import textwrap

    longest = max(len(line) for line in text.splitlines())
    return textwrap.fill(" ".join(text.split()), width=max(10, int(longest * shrink * 0.95)))


def _fit_suptitle(fig: Figure) -> None:
    """Centre the suptitle over the panels and wrap it to their width, so a larger font neither runs off the
    figure nor into a legend beside the panels (matplotlib's own wrap uses the whole figure's width)."""
    title = getattr(fig, "_suptitle", None)  # Figure.suptitle's Text; matplotlib has no public getter for it
    axes = [ax.get_position() for ax in fig.axes if ax.get_visible()]
    if title is None or not title.get_text() or not axes:
        return
    fig.draw_without_rendering()  # the panels' places and the title's extent at its new size
    axes = [ax.get_position() for ax in fig.axes if ax.get_visible()]
    left, right = min(box.x0 for box in axes), max(box.x1 for box in axes)
    title.set_x((left + right) / 2)
    width = title.get_window_extent().width / fig.bbox.width  # as a share of the figure, like the panels' span
    if width > right - left:
        title.set_text(_rewrapped(title.get_text(), (right - left) / width))


def save_figure(fig: Figure, stem: str | os.PathLike[str], dpi: int = DPI) -> dict[str, Path]:
    """Write ``stem``.png (``dpi``) and ``stem``.pdf atomically, then close the figure.

    Its text is first made legible where the site shows it (`legible`), and the PNG records the smallest font
    size (SMALLEST_FONT_KEY). The PDF's CreationDate and the PNG's Software tag are dropped so that re-running a
    pipeline with the same inputs reproduces both files byte for byte, across matplotlib versions too (PNG from
    Agg carries no timestamp).
    """
    if not isinstance(fig, Figure):
        raise ValueError(f"save_figure: expected a matplotlib Figure, got {type(fig).__name__}.")
    paths = {"png": Path(f"{os.fspath(stem)}.png"), "pdf": Path(f"{os.fspath(stem)}.pdf")}
    try:
        smallest = legible(fig, dpi)
        with atomic_path(paths["png"]) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi, metadata={"Software": None, SMALLEST_FONT_KEY: f"{smallest:.2f}"})
        with atomic_path(paths["pdf"]) as tmp:
            fig.savefig(tmp, format="pdf", metadata={"CreationDate": None})
    finally:
        plt.close(fig)  # releases pyplot's reference if the caller made the figure with pyplot
    return paths


def show_figure(fig: Figure, stem: str | os.PathLike[str] | None = None, width: int = 900) -> None:
    """Display ``fig`` inline in a notebook as a PNG; with a ``stem``, save it first (``save_figure``) and show that file.

    The PNG itself is displayed rather than relying on matplotlib's inline backend (which
    ``MPLBACKEND=Agg`` turns off and which ignores figures made without pyplot), so an executed
    notebook shows exactly the committed figure.
    """
    import io

    from IPython.display import Image, display

    if stem is not None:
        display(Image(filename=str(save_figure(fig, stem)["png"]), width=width))
        return
    if not isinstance(fig, Figure):
        raise ValueError(f"show_figure: expected a matplotlib Figure, got {type(fig).__name__}.")
    buffer = io.BytesIO()
    legible(fig)
    fig.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    plt.close(fig)
    display(Image(data=buffer.getvalue(), width=width))


def roc_curves(df: pd.DataFrame, max_columns: int = 4) -> Figure:
    """ROC curves (OOD = positive), one panel per env, colour = method, line style = measure.

    Expects columns fpr, tpr, method, measure, env, one row per ROC point (e.g.
    ``metrics.roc_points`` output with labels added). A grey diagonal marks chance. Panels wrap
    after ``max_columns`` (8 envs: two rows), with one legend beside the grid.
    """
    require_columns(df, ["fpr", "tpr", "method", "measure", "env"], "roc_curves")
    envs = list(pd.unique(df["env"]))
    fig, axes = _grid_figure(len(envs), max_columns)
    for ax, env in zip(axes, envs):
        sub = df[df["env"] == env]
        # estimator=None: ROC points share fpr values at vertical steps and must not be averaged.
        sns.lineplot(data=sub, x="fpr", y="tpr", hue="method", style="measure", estimator=None, ax=ax,
                     hue_order=list(pd.unique(df["method"])), style_order=list(pd.unique(df["measure"])))
        ax.plot([0, 1], [0, 1], color="grey", linestyle=":", linewidth=1)
        ax.set(title=str(env), xlim=(0, 1), ylim=(0, 1.01))
        ax.set(xlabel="FPR (ID flagged as OOD)", ylabel="TPR (OOD detected)")
    _legend_beside_grid(fig, axes)
    return fig


def uncertainty_over_time(df: pd.DataFrame) -> Figure:
    """Uncertainty per evaluation step, colour = method; a red vertical line where ID ends and OOD begins.

    Expects columns step, score, method, phase ("id" or "ood"); all ID steps must
    come before all OOD steps (the states are evaluated as one ID-then-OOD stream).
    """
    require_columns(df, ["step", "score", "method", "phase"], "uncertainty_over_time")
    phases = set(pd.unique(df["phase"]))
    if not phases <= {"id", "ood"} or len(phases) != 2:
        raise ValueError(
            f"uncertainty_over_time: phase must take both values 'id' and 'ood' only, got {sorted(map(str, phases))}."
        )
    last_id, first_ood = df.loc[df["phase"] == "id", "step"].max(), df.loc[df["phase"] == "ood", "step"].min()
    if not last_id < first_ood:
        raise ValueError(f"uncertainty_over_time: ID steps must precede OOD steps, but the last ID step is {last_id} "
                         f"and the first OOD step is {first_ood}; number the OOD states after the ID ones.")
    fig, (ax,) = _new_figure(1, legend_width=1.6)
    sns.lineplot(data=df, x="step", y="score", hue="method", errorbar=None, linewidth=0.8, ax=ax,
                 hue_order=list(pd.unique(df["method"])))
    ax.axvline((last_id + first_ood) / 2, color="red", linewidth=1.5)
    ax.set(xlabel="step (ID, then OOD)", ylabel="uncertainty")
    _keep_last_legend([ax], outside=True)  # a legend inside would hide the noisiest stretch of the traces
    return fig


def uncertainty_from_spawn(df: pd.DataFrame, spawn_steps: int) -> Figure:
    """Relative uncertainty per step after reset, colour = method, above the share of steps in the air.

    Expects columns step, relative, method, airborne (bool). ``relative`` is a run's uncertainty
    over its own mean after the spawn window, so methods with different spreads share one axis;
    a dashed line marks the end of the spawn window.
    """
    require_columns(df, ["step", "relative", "method", "airborne"], "uncertainty_from_spawn")
    fig = Figure(figsize=(6.4, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 1])
    sns.lineplot(data=df, x="step", y="relative", hue="method", errorbar=None, linewidth=0.9, ax=top,
                 hue_order=list(pd.unique(df["method"])))
    top.axhline(1.0, color="grey", linewidth=0.6)
    top.set(ylabel="uncertainty / its mean later")
    air = df.groupby("step")["airborne"].mean()
    bottom.fill_between(air.index, air.to_numpy(), step="mid", color="tab:grey", alpha=0.6)
    bottom.set(xlabel="step after reset", ylabel="in the air", ylim=(0, 1))
    for ax in (top, bottom):
        ax.axvline(spawn_steps - 0.5, color="black", linestyle="--", linewidth=0.8)
    return fig


def training_curves(df: pd.DataFrame, max_columns: int = 4) -> Figure:
    """Episode reward over training, one panel per env: mean over seeds with a ±1 std band.

    Expects columns timesteps, reward, method, env, seed; seeds should log at the
    same timesteps (bin them first otherwise) so the mean is taken over seeds. Panels wrap
    after ``max_columns``, so the four MuJoCo envs and the four games make two rows as in the paper.
    """
    require_columns(df, ["timesteps", "reward", "method", "env", "seed"], "training_curves")
    envs = list(pd.unique(df["env"]))
    fig, axes = _grid_figure(len(envs), max_columns)  # no shared y: reward scales differ per env
    for ax, env in zip(axes, envs):
        sns.lineplot(data=df[df["env"] == env], x="timesteps", y="reward", hue="method", errorbar="sd", ax=ax,
                     hue_order=list(pd.unique(df["method"])))
        ax.set(title=str(env), xlabel="timesteps", ylabel="episode reward")
    _keep_last_legend(axes)
    return fig


def normalized_bars(df: pd.DataFrame) -> Figure:
    """Mean uncertainty under each perturbation relative to unperturbed ID states (ID = 1.0).

    Expects columns perturbation, method, ratio, where ratio is already divided by
    the method's mean ID uncertainty. Several rows per (perturbation, method), e.g.
    seeds, are averaged and shown with a ±1 std error bar. Dashed line: ratio 1.
    """
    require_columns(df, ["perturbation", "method", "ratio"], "normalized_bars")
    fig, (ax,) = _new_figure(1)
    fig.set_figwidth(max(PANEL_SIZE[0], 0.9 * df["perturbation"].nunique() * max(1, df["method"].nunique()) ** 0.5))
    sns.barplot(data=df, x="perturbation", y="ratio", hue="method", errorbar="sd", ax=ax,
                order=list(pd.unique(df["perturbation"])), hue_order=list(pd.unique(df["method"])))
    ax.axhline(1.0, color="black", linestyle="--", linewidth=1)
    ax.set(xlabel="perturbation", ylabel="uncertainty / ID uncertainty")
    ax.tick_params(axis="x", labelrotation=30)
    return fig


def score_aurocs(df: pd.DataFrame, max_columns: int = 4) -> Figure:
    """AUROC of several OOD scores per method, one panel per env: one dot per run, a bar for the mean.

    Expects columns env, method, score, auroc (long form, one row per run and score). A dashed line
    marks chance (0.5), so scores that rank OOD states below ID states stand out.
    """
    require_columns(df, ["env", "method", "score", "auroc"], "score_aurocs")
    envs = list(pd.unique(df["env"]))
    fig, axes = _grid_figure(len(envs), max_columns)
    order, hue_order = list(pd.unique(df["method"])), list(pd.unique(df["score"]))
    for ax, env_id in zip(axes, envs):
        sub = df[df["env"] == env_id]
        sns.barplot(data=sub, x="method", y="auroc", hue="score", order=order, hue_order=hue_order, errorbar=None,
                    alpha=0.5, ax=ax)
        with seeded_jitter():
            sns.stripplot(data=sub, x="method", y="auroc", hue="score", order=order, hue_order=hue_order,
                          dodge=True, size=3, legend=False, ax=ax)
        ax.axhline(0.5, color="black", linestyle="--", linewidth=0.8)
        ax.set(title=env_id, xlabel="", ylabel="AUROC", ylim=(0, 1))
        ax.tick_params(axis="x", labelrotation=30)
    _legend_beside_grid(fig, axes, title="score")
    return fig


def timeline(df: pd.DataFrame, event_step: float | None = None, reference: float | None = None,
             ylabel: str = "score") -> Figure:
    """Scores over the steps of one episode, one panel per ``panel``, colour = ``measure``.

    Expects columns step, score, measure, panel. A red vertical line marks ``event_step`` (e.g.
    where the physics changed) and a dashed horizontal line ``reference`` (e.g. a threshold).
    """
    require_columns(df, ["step", "score", "measure", "panel"], "timeline")
    panels = list(pd.unique(df["panel"]))
    fig = Figure(figsize=(PANEL_SIZE[0] * 2.2, PANEL_SIZE[1] * 0.8 * len(panels)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = list(fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0])
    for ax, panel in zip(axes, panels):
        sub = df[df["panel"] == panel]
        sns.lineplot(data=sub, x="step", y="score", hue="measure", hue_order=list(pd.unique(sub["measure"])),
                     errorbar=None, linewidth=1.0, ax=ax)
        if event_step is not None:
            ax.axvline(event_step, color="red", linewidth=1.5)
        if reference is not None:
            ax.axhline(reference, color="black", linestyle="--", linewidth=0.8)
        ax.set(title=str(panel), ylabel=ylabel)
        sns.move_legend(ax, "upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, title=None)
    axes[-1].set(xlabel="step")
    return fig


#: Characters of a panel title per inch of panel at 1 pt (100 / size: an average character 0.72 em wide, with room
#: for capitals; `legible` re-wraps a title still wider than its panel).
CHARS_PER_INCH_AT_1PT = 100


def image_grid(images: list, titles: list[str], ncols: int | None = None, panel_width: float = 2.4,
               suptitle: str | None = None) -> Figure:
    """Images (H, W, 3) RGB or (H, W) grey in a grid, each with its (wrapped) title; axes hidden."""
    if len(images) != len(titles) or not images:
        raise ValueError(f"image_grid: need one title per image and at least one image, got {len(images)} images "
                         f"and {len(titles)} titles.")
    import textwrap

    ncols = ncols or len(images)
    nrows = -(-len(images) // ncols)
    first = images[0]
    aspect = first.shape[0] / first.shape[1]
    size = min_font_pt(panel_width * ncols)  # the site's legible size: titles wrap at the panel's width in it
    wrapped = [textwrap.fill(title, width=int(panel_width * CHARS_PER_INCH_AT_1PT / size)) for title in titles]
    lines = max(text.count("\n") + 1 for text in wrapped)
    title_height = lines * size * 1.3 / 72 + 0.2  # inches above each image for its title: the images keep their size
    fig = Figure(figsize=(panel_width * ncols, (panel_width * aspect + title_height) * nrows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[len(images):]:
        ax.set_axis_off()
    for ax, image, title in zip(axes, images, wrapped):
        ax.set(xticks=[], yticks=[])  # the frame stays: a white image is still seen
        ax.imshow(image, cmap="gray" if image.ndim == 2 else None, vmin=0, vmax=255, interpolation="nearest")
        ax.set_title(title, fontsize=size)
    if suptitle:
        fig.suptitle(suptitle, fontsize="small")
    return fig


def pareto_scatter(df: pd.DataFrame) -> Figure:
    """Reward vs. AUROC of every configuration (colour = method); Pareto-optimal ones enlarged with a black edge.

    Expects columns reward, auroc, method, is_pareto (bool). The Pareto set is the
    caller's: this function only draws it.
    """
    require_columns(df, ["reward", "auroc", "method", "is_pareto"], "pareto_scatter")
    if not pd.api.types.is_bool_dtype(df["is_pareto"]):
        raise ValueError(
            f"pareto_scatter: column 'is_pareto' must be boolean, got dtype {df['is_pareto'].dtype}; use .astype(bool)."
        )
    fig, (ax,) = _new_figure(1, legend_width=1.6)
    hue_order = list(pd.unique(df["method"]))
    sns.scatterplot(data=df, x="reward", y="auroc", hue="method", hue_order=hue_order, s=18, alpha=0.6,
                    linewidth=0, ax=ax)
    front = df[df["is_pareto"]]
    if not front.empty:
        sns.scatterplot(data=front, x="reward", y="auroc", hue="method", hue_order=hue_order, s=70,
                        edgecolor="black", linewidth=1.2, legend=False, ax=ax)
    ax.set(xlabel="episode reward", ylabel="OOD AUROC")
    _keep_last_legend([ax], outside=True)
    return fig


def performance_profiles(df: pd.DataFrame, xlabel: str, reference: float | None = None, panel: str = "family",
                         max_columns: int = 4) -> Figure:
    """Performance profiles (Agarwal et al. 2021): the fraction of runs scoring above tau, one panel per ``panel``.

    Expects `aggregates.profiles_by_env_family` output (columns method, tau, fraction, fraction_low,
    fraction_high, seeds_per_env, n_envs and ``panel``): one line per method, its stratified-bootstrap
    band shaded where it has one (none with one seed per env, which the panel title says). A dotted
    line marks ``reference`` (chance AUROC 0.5, the baseline's reward 1.0). A curve above another
    everywhere means more runs above every threshold, whatever threshold a reader cares about.
    """
    require_columns(df, ["method", "tau", "fraction", "fraction_low", "fraction_high", "seeds_per_env", "n_envs",
                         panel], "performance_profiles")
    panels = list(pd.unique(df[panel]))
    fig, axes = _grid_figure(len(panels), max_columns)
    methods = list(pd.unique(df["method"]))
    colors = dict(zip(methods, sns.color_palette(n_colors=max(1, len(methods)))))
    handles: dict[str, object] = {}
    for ax, name in zip(axes, panels):
        sub = df[df[panel] == name]
        for method, curve in sub.groupby("method", sort=False):
            (line,) = ax.plot(curve["tau"], curve["fraction"], color=colors[method], linewidth=1.4, label=method)
            handles.setdefault(method, line)
            if curve["fraction_low"].notna().any():
                ax.fill_between(curve["tau"], curve["fraction_low"], curve["fraction_high"], color=colors[method],
                                alpha=0.2, linewidth=0)
        if reference is not None:
            ax.axvline(reference, color="grey", linestyle=":", linewidth=1)
        seeds = ", ".join(sorted({f"{int(s)} seed{'s' if s != 1 else ''} x {int(n)} envs"
                                  for s, n in zip(sub["seeds_per_env"], sub["n_envs"])}))
        band = "" if sub["fraction_low"].notna().any() else ", no band: one seed per env"
        ax.set(title=f"{name} ({seeds}{band})", xlabel=xlabel, ylabel="fraction of runs > tau", ylim=(-0.02, 1.02))
        ax.title.set_fontsize("small")
    fig.legend(list(handles.values()), list(handles), loc="outside center right", frameon=False)
    return fig


__all__ = ["save_figure", "show_figure", "legible", "roc_curves", "uncertainty_over_time", "training_curves",
           "normalized_bars",
           "timeline", "image_grid", "pareto_scatter", "performance_profiles"]


def auroc_with_intervals(df: pd.DataFrame, max_columns: int = 4) -> Figure:
    """AUROC per method and measure with its 95% interval, one panel per env: the headline figure of the site.

    Expects columns env, method, measure, auroc, auroc_ci_low, auroc_ci_high (notebook 3's `ood_metrics` rows of
    one OOD set), one row per (env, method, measure). Each method is a column of the panel, each measure a dot
    beside it with its interval as an error bar; the dashed line is chance (0.5). Read it as "which method's
    uncertainty separates OOD states in this env, and how sure are we": intervals, not only means.
    """
    require_columns(df, ["env", "method", "measure", "auroc", "auroc_ci_low", "auroc_ci_high"], "auroc_with_intervals")
    envs = list(pd.unique(df["env"]))
    methods = list(pd.unique(df["method"]))
    measures = list(pd.unique(df["measure"]))
    fig, axes = _grid_figure(len(envs), max_columns)
    offsets = np.linspace(-0.2, 0.2, len(measures)) if len(measures) > 1 else np.zeros(1)
    colours = sns.color_palette(n_colors=len(measures))
    for ax, env in zip(axes, envs):
        sub = df[df["env"] == env]
        for offset, colour, measure in zip(offsets, colours, measures):
            rows = sub[sub["measure"] == measure].set_index("method").reindex(methods)
            x = np.arange(len(methods)) + offset
            low = (rows["auroc"] - rows["auroc_ci_low"]).clip(lower=0)
            high = (rows["auroc_ci_high"] - rows["auroc"]).clip(lower=0)
            ax.errorbar(x, rows["auroc"], yerr=[low, high], fmt="o", color=colour, label=measure, capsize=3)
        ax.axhline(0.5, color="grey", linestyle="--", linewidth=1)
        ax.set_xticks(np.arange(len(methods)), methods, rotation=30, ha="right")
        ax.set(title=str(env), ylim=(0, 1.02), ylabel="AUROC (95% interval)")
    handles, labels = axes[-1].get_legend_handles_labels()
    fig.legend(handles, labels, title="measure", loc="outside right upper", frameon=False)
    return fig
