"""What the results site shows fits a reader's screen, checked without a browser (test_site.py checks it in one):
tables split and wrapped (scripts/site_tables.py), figure text legible at its displayed size (the figures the
notebooks declare, from their committed PNGs: no notebook is re-run).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

import build_site  # noqa: E402
import site_tables  # noqa: E402
from paper_lib.reporting import display  # noqa: E402
from paper_lib.reporting.plots import SMALLEST_FONT_KEY  # noqa: E402

ZWSP, NBSP, WJ = site_tables.ZWSP, site_tables.NBSP, site_tables.WORD_JOINER


def _tables(markdown: str) -> list[list[str]]:
    """The pipe tables of `markdown`, each as its lines."""
    tables: list[list[str]] = []
    previous = False
    for line in markdown.splitlines():
        if line.startswith("|"):
            if not previous:
                tables.append([])
            tables[-1].append(line)
        previous = line.startswith("|")
    return tables


def test_the_rewards_table_is_shown_as_mujoco_and_atari_tables():
    """Table 1 (10 columns, 8 envs) scrolled at 1400 px: two tables, each with method, inference and actions."""
    committed = (ROOT / "results" / "paper" / "tables" / "rewards.md").read_text()
    (whole,) = _tables(committed)
    mujoco, atari = _tables(site_tables.fit_tables(committed))
    heads = [[c.strip().replace(WJ, "") for c in site_tables.cells(t[0])] for t in (mujoco, atari)]
    assert heads[0] == ["method", "inference", "actions", "Ant-v5", "HalfCheetah-v5", "Swimmer-v5", "Walker2d-v5"]
    assert heads[1][:3] == ["method", "inference", "actions"] and all("NoFrameskip" in h for h in heads[1][3:])
    assert len(mujoco) == len(atari) == len(whole)
    assert "*MuJoCo:*" in site_tables.fit_tables(committed) and "*Atari:*" in site_tables.fit_tables(committed)


def test_a_table_of_one_env_family_or_inside_a_code_fence_is_not_split():
    one = "| method | Ant-v5 | Swimmer-v5 |\n|:--|--:|--:|\n| baseline | 1.0 | 2.0 |\n"
    assert len(_tables(site_tables.fit_tables(one))) == 1
    fenced = "```\n| m | Ant-v5 | SeaquestNoFrameskip-v4 |\n|---|---|---|\n| a | 1 | 2 |\n```\n"
    assert site_tables.fit_tables(fenced) == fenced


@pytest.mark.parametrize("cell, shown", [
    (" 0.014 [-0.083, 0.110] ", f" 0.014 [-0.083,{NBSP}0.110] "),  # breaks before its interval only
    (" 4961.5 ± 890.7 (n=3) ", f" 4961.5{NBSP}±{NBSP}890.7 (n=3) "),
    (" 4 min 32 s (installed) ", " 4 min 32 s (installed) "),  # text: wraps where it likes
    (" mahalanobis_features ", f" mahalanobis_{ZWSP}features "),
    (" 1;2;3 ", f" 1;{ZWSP}2;{ZWSP}3 "),
    (" Walker2d-v5 ", f" Walker2d-{WJ}v5 "),  # an env's name never splits at its hyphen
    (" `knn_obs` ", " `knn_obs` "), ("  ", "  ")])
def test_numbers_stay_whole_and_text_wraps_at_its_joints(cell, shown):
    assert site_tables.wrap_cell(cell) == shown


def test_a_wide_dataframe_is_split_per_group_of_measures_and_loses_its_default_index():
    """pandas' 0..n-1 index is noise; 16 measures are two tables, each with the text columns that name a row."""
    wide = pd.DataFrame({"env": ["Ant-v5", "Walker2d-v5"], "method": ["baseline", "mc_dropconnect"],
                         **{f"id_alarms_per_1000_steps_{i}": [0.125, 25.5] for i in range(14)}})
    shown = site_tables.fit_dataframe(wide._repr_html_())
    assert shown.count("<table") == 2 and "<th>0</th>" not in shown and "<th>1</th>" not in shown
    for table in shown.split("</table>")[:2]:
        assert "<th>env</th>" in table and f"mc_{ZWSP}dropconnect" in table and f"Walker2d-{WJ}v5" in table
    assert shown.count("id_alarms_per_1000_steps_") == 14
    narrow = pd.DataFrame({"env": ["Ant-v5"], "auroc": [0.9]}, index=["kept"])
    assert site_tables.fit_dataframe(narrow._repr_html_()).count("<table") == 1
    assert "<th>kept</th>" in site_tables.fit_dataframe(narrow._repr_html_())


def _declared_pngs() -> list[tuple[Path, str]]:
    """Every committed figure a notebook declares, with the DVC stage that draws it."""
    profile = build_site.active_profile()
    stages = build_site.notebook_stages()
    files = []
    for source in sorted((ROOT / "notebooks").glob("*.ipynb")):
        executed = build_site.executed_notebooks(profile) / source.name
        if executed.is_file():
            stage = stages[source.name][0]
            files += [(f.file, stage) for f in build_site.declared_figures(source, profile, ROOT, executed)]
    return files


def test_every_declared_figure_shows_its_text_legibly_on_the_site():
    """From each committed PNG: its width, dpi and recorded smallest font (save_figure writes it) give the size
    its text shows at on the site; every figure a notebook declares must show MIN_FONT_PX or more.

    A PNG without the record was drawn before save_figure made text legible (issue 68): `make reproduce` re-draws
    every table stage's, so those must all carry it. The experiments that play episodes (the guard, spawn and value
    level notebooks) draw theirs only when `make recollect` plays them again, which a rebuild never does: theirs are
    judged where they carry the record and are otherwise left to that run (docs/deviations.md)."""
    from PIL import Image

    from paper_lib.pipeline.reproduce import EXPERIMENT_STAGES

    files = _declared_pngs()
    assert files, "no notebook declares a committed figure"
    unrecorded, small = [], []
    for path, stage in files:
        with Image.open(path) as image:
            width, recorded = image.size[0], image.info.get(SMALLEST_FONT_KEY)
            dpi = round(image.info.get("dpi", (display.DPI,))[0])
        if recorded is None:
            if stage not in EXPERIMENT_STAGES:
                unrecorded.append(path.relative_to(ROOT).as_posix())
        elif (shown := display.displayed_font_px(float(recorded), width, dpi)) < display.MIN_FONT_PX - 0.01:
            small.append(f"{path.relative_to(ROOT)}: {recorded} pt shows at {shown:.1f} px")
    assert not small, "text too small on the site:\n" + "\n".join(small)
    assert not unrecorded, (f"{len(unrecorded)} of {len(files)} declared figures record no smallest font (drawn before "
                            f"fonts were made legible): `make reproduce` re-draws them; first: {unrecorded[:3]}")
