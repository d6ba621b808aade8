"""Figures whose text a reader of the results site can read: at least display.MIN_FONT_PX at the size it is shown.

The site shows a figure at half its pixel width, capped by its column (paper_lib.reporting.display); save_figure
raises every smaller text to the floor its width needs (plots.legible) and records the smallest size in the PNG.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.text import Text
from PIL import Image

from paper_lib.reporting import display, plots


def test_the_displayed_size_follows_from_width_dpi_and_the_sites_scale():
    """A 16-inch grid at 150 dpi (2400 px) shows in the 1042 px column: 10 pt reads 9.0 px; up to 13.9 inches it
    shows at half size, 10 pt at 10.4 px, and needs 8.64 pt for 9 px."""
    assert display.shown_width_px(2400) == display.COLUMN_PX and display.shown_width_px(1200) == 600
    assert display.displayed_font_px(10, 2400) == pytest.approx(10 / 72 * 150 * 1042 / 2400)
    assert display.displayed_font_px(10, 1200) == pytest.approx(10 / 72 * 75)
    assert display.min_font_pt(8.0) == pytest.approx(9 * 72 / 75)
    assert display.min_font_pt(16.0) == pytest.approx(9 * 72 * 16 / 1042)
    assert display.displayed_font_px(display.min_font_pt(21.2), 21.2 * 150) == pytest.approx(display.MIN_FONT_PX)
    with pytest.raises(ValueError, match="must be positive"):
        display.shown_width_px(0)


def _eight_env_roc() -> pd.DataFrame:
    rows = [dict(env=f"Env{i}-v5", method=method, measure=measure, fpr=fpr, tpr=tpr)
            for i in range(8) for method in ("baseline", "masksembles") for measure in ("value_std", "policy_std")
            for fpr, tpr in ((0, 0), (0, 0.5), (0.5, 0.9), (1, 1))]
    return pd.DataFrame(rows)


def _smallest_shown_px(fig, dpi: int = display.DPI) -> float:
    """The smallest visible text of a drawn figure, in CSS px as the site shows it."""
    fig.draw_without_rendering()
    sizes = [t.get_fontsize() for t in fig.findobj(Text) if t.get_text() and t.get_visible()]
    return display.displayed_font_px(min(sizes), fig.get_figwidth() * dpi, dpi)


def test_a_wide_multi_panel_figure_is_saved_with_every_text_legible_on_the_site(tmp_path):
    """An 8-env ROC grid (16 inches) with a 'small' suptitle and an 'x-small' panel title: below 9 px as drawn,
    every text at 9 px or more once saved; a large title keeps its size; the PNG records the smallest size."""
    fig = plots.roc_curves(_eight_env_roc())
    fig.suptitle("ROC curves of eight envs", fontsize="small")
    fig.axes[0].set_title("Env0-v5", fontsize="x-small")
    fig.axes[1].set_title("Env1-v5", fontsize=16)
    assert _smallest_shown_px(fig) < display.MIN_FONT_PX  # the check sees small text where there is some
    png = plots.save_figure(fig, tmp_path / "roc")["png"]
    assert _smallest_shown_px(fig) >= display.MIN_FONT_PX - 0.01
    assert fig.axes[1].title.get_fontsize() == 16
    with Image.open(png) as image:
        width, recorded = image.size[0], float(image.info[plots.SMALLEST_FONT_KEY])
    assert width == 2400 and display.displayed_font_px(recorded, width) >= display.MIN_FONT_PX - 0.01


def test_image_grid_titles_are_legible_and_wrapped_to_their_panel():
    images = [np.zeros((30, 40, 3), dtype=np.uint8)] * 3
    fig = plots.image_grid(images, ["OOD gravity: g = -14.2 m/s^2 drawn from the paper's range"] * 3)
    title = fig.axes[0].title
    shown = display.displayed_font_px(title.get_fontsize(), fig.get_figwidth() * display.DPI)
    assert shown >= display.MIN_FONT_PX - 0.01
    assert max(map(len, title.get_text().splitlines())) <= 2.4 * plots.CHARS_PER_INCH_AT_1PT / title.get_fontsize()


def test_four_pareto_panels_wrap_into_two_rows():
    """The study's four-env Pareto plot: two rows of two panels, not a 17-inch strip the site shows 190 px high."""
    from paper_lib.study.plots import front_scatter

    df = pd.DataFrame([dict(env=env, method=method, reward=float(r), auroc=0.5 + r / 20, is_pareto=r == 9)
                       for env in ("Ant-v5", "HalfCheetah-v5", "Walker2d-v5", "Swimmer-v5")
                       for method in ("baseline", "masksembles") for r in range(10)])
    fig = front_scatter(df)
    rows = {round(ax.get_position().y0, 2) for ax in fig.axes}
    assert len(fig.axes) == 4 and len(rows) == 2 and fig.get_figwidth() < 13


def test_a_long_panel_title_wraps_to_its_panel_and_crowded_tick_labels_stand_upright(tmp_path):
    """Raised to the legible size, text must not run into its neighbour: a title wider than its panel wraps,
    x tick labels that overlap turn upright; labels that fit stay as drawn."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(16, 3), layout="constrained")
    FigureCanvasAgg(fig)
    crowded, roomy = fig.subplots(1, 2)
    crowded.set_xticks(range(6), [f"HalfCheetah masksembles {i}" for i in range(6)])
    crowded.set_title("Atari, value_std (1 seed x 4 envs, no band: one seed per env) " * 3, fontsize="small")
    roomy.set_xticks(range(3), ["a", "b", "c"])
    plots.save_figure(fig, tmp_path / "crowded")
    assert crowded.title.get_text().count("\n") >= 1
    assert crowded.title.get_window_extent().width <= crowded.get_window_extent().width
    assert {label.get_rotation() for label in crowded.get_xticklabels()} == {90}
    assert {label.get_rotation() for label in roomy.get_xticklabels()} == {0}
