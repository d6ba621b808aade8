"""How large a figure's text looks on the results website, and how large it must be drawn to be read there.

A figure is saved at DPI (150) and the site shows it at DISPLAY_SCALE (half) of its pixel width, capped by the page's
column (COLUMN_PX at a 1400 px window: a figure wider than COLUMN_PX / DISPLAY_SCALE px is shrunk further). Text of
`pt` points thus shows `pt / 72 * DPI * shown / drawn` CSS px high: matplotlib's default 10 pt shows at 10.4 px in a
figure of up to 13.9 inches, 'x-small' at 7.2 px, and a 21-inch four-panel strip's 10 pt at 6.8 px (issue 68).
`min_font_pt` turns MIN_FONT_PX back into the points a figure of a given width needs; `plots.legible` applies it.

Plain arithmetic, no plotting import: the site build (scripts/build_site.py) reads DISPLAY_SCALE from here too.
"""

from __future__ import annotations

#: The resolution figures are saved at (`plots.save_figure`).
DPI = 150
#: The share of its pixel width a figure is shown at on the site: a 10 pt title at 150 dpi reads about 10 px high.
DISPLAY_SCALE = 0.5
#: The width of a notebook page's column at a 1400 px window, in CSS px (measured in chromium; the site's tests check
#: that no figure shows wider).
COLUMN_PX = 1042
#: The least height of text, in CSS px, a reader reads without zooming.
MIN_FONT_PX = 9.0
POINTS_PER_INCH = 72


def shown_width_px(drawn_px: float) -> float:
    """The CSS px the site shows a figure of `drawn_px` pixels at: DISPLAY_SCALE of it, at most the column."""
    if drawn_px <= 0:
        raise ValueError(f"a figure's width must be positive, got {drawn_px} px")
    return min(DISPLAY_SCALE * drawn_px, COLUMN_PX)


def displayed_font_px(font_pt: float, drawn_px: float, dpi: float = DPI) -> float:
    """The CSS px that text of `font_pt` points shows at in a figure `drawn_px` pixels wide saved at `dpi`."""
    return font_pt / POINTS_PER_INCH * dpi * shown_width_px(drawn_px) / drawn_px


def min_font_pt(width_in: float, dpi: float = DPI, min_px: float = MIN_FONT_PX) -> float:
    """The least font size in points for text to show `min_px` high in a figure `width_in` inches wide."""
    return min_px / displayed_font_px(1.0, width_in * dpi, dpi)
