"""Build the results website (`make site`): docs/ and the executed notebooks as static HTML, offline.

    .venv/bin/python scripts/build_site.py          # build/site/index.html

Sphinx with myst-nb and sphinx-book-theme. Nothing is fetched and no notebook is executed: the pages show the
committed executed notebooks of the active profile (`results/<profile>/notebooks/`) as they are, so the site is
the committed results, never a fresh computation. The sources are assembled in `build/site-src/` (nothing is
written into docs/ or results/), laid out as the repository is (README.md, docs/*.md, notebooks/*.ipynb), so the
docs' links between each other, to the README and to the notebooks resolve on the site as they do on disk (a link
to a committed executed notebook goes to its page; one to any other repository file names the path):

- the home page answers first: the claims x envs matrix of verdicts (from the committed claims table, each cell
  linking to its evidence on the claims page), the headline figure, the reading, one line per committed table
  (with its CSV), then one line per executed notebook naming its notebook and DVC stage, then how to cite;
- one page per executed notebook, headed by where it comes from (notebook, committed copy, DVC stage, read
  from dvc.yaml: never typed by hand); code hidden behind a toggle; each figure its notebook's source declares
  (cell metadata `figures`) numbered, captioned, with alt text and its PNG; each committed table with its CSV;
  tables made to fit the column at 1400 px (scripts/site_tables.py: split, numbers whole, text wrapped);
- every page's foot names the commit it was built from;
- docs/results.md (every generated table), docs/deviations.md, docs/study.md and the rest of the manual.

Files in `build/site-src/` are rewritten only when their content changes, so a second build re-reads only what
changed (Sphinx is incremental).
"""

from __future__ import annotations

import argparse
import posixpath
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import unquote

import yaml
from site_tables import fit_dataframe, fit_tables

if TYPE_CHECKING:
    import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
BUILD = ROOT / "build"
SOURCE_DIR = BUILD / "site-src"
SITE_DIR = BUILD / "site"
DOCTREES = BUILD / "site-doctrees"
WARNINGS_FILE = BUILD / "site-warnings.txt"
#: The docs pages in the sidebar's first groups, in this order; every other docs/*.md page goes under "Manual".
RESULTS_PAGES = ("results",)
DEVIATIONS_AND_STUDY = ("deviations", "study")
MANUAL_FIRST = ("index", "methods", "ood_benchmark", "guard", "ensembles", "benchmarks", "pipeline", "layout")
#: A Markdown link (not an image): [label](target), the target without spaces or a title.
MD_LINK = re.compile(r"(?<!!)\[([^\]]*)\]\(([^)\s]+)\)")
STAGE_CMD = re.compile(r"notebook_run\s+(notebooks/\S+\.ipynb)")
EXECUTED_OUT = re.compile(r"^results/\$\{run\.profile\}/notebooks/([^/]+\.ipynb)$")

CONF_PY = '''"""Sphinx settings of the results website; written by scripts/build_site.py (edit it there)."""
project = {project!r}
html_title = {title!r}
extensions = ["myst_nb"]
nb_execution_mode = "off"  # the committed executed notebooks are shown as they are; nothing runs at build time
nb_merge_streams = True
nb_render_markdown_format = "myst"  # the notebooks print their tables as Markdown: pipe tables need MyST (not CommonMark)
myst_heading_anchors = 4  # docs link to headings (pipeline.md#timings) as GitHub names them
exclude_patterns = ["_build", "**/.ipynb_checkpoints"]
html_theme = "sphinx_book_theme"
html_theme_options = {{"home_page_in_toc": True, "show_navbar_depth": 1, "use_download_button": False,
                      "show_toc_level": 2, "extra_footer": {footer!r},
                      # the verdict matrix and the figures take the whole width: no "Contents" column beside them
                      "secondary_sidebar_items": {secondary!r}}}
html_static_path = ["_static"]
html_extra_path = ["files"]  # every offered PNG and CSV also at its repository path, so a figure opens full size
html_favicon = "_static/favicon.svg"  # without one the browser asks for /favicon.ico, a 404 in the console
html_context = {{"default_mode": "light"}}  # the theme's mode switch logs an error on a first visit without one
html_css_files = ["results.css"]
html_js_files = ["file_search.js"]  # after documentation_options.js, before the search page's searchtools.js
html_copy_source = False  # the sources are in the repository; copying multi-MB notebooks again is waste
html_show_sourcelink = False
html_last_updated_fmt = None
suppress_warnings = ["myst.header"]  # docs/results.md's pasted tables sit under H3 headings below its H1, as on GitHub
'''


#: Tables fit their column: text wraps (a claim or an evidence sentence on one line made the claims table 5,000 px
#: wide), numbers never break (a number split over two lines misreads: site_tables.py joins each number's parts
#: with no-break spaces, so no cell needs `nowrap`, which made 10 of 73 tables scroll at 1400 px); a table still
#: wider than the column scrolls inside its own box (`.table-wrapper`, MyST-NB's and ours), never the page. Figures fill the column; the verdict
#: matrix's colours are defined here, once.
RESULTS_CSS = """.bd-page-width { max-width: 120rem; }
.bd-main .bd-content .bd-article-container { max-width: 100%; }
.bd-article table { display: block; max-width: 100%; overflow-x: auto; font-size: 0.85rem; }
.bd-article table td, .bd-article table th { padding: 0.2rem 0.3rem; font-size: 0.8rem; }
.bd-article table td, .bd-article table th { white-space: normal; overflow-wrap: break-word; vertical-align: top; }
.bd-article code.literal, .bd-article code.literal span.pre { white-space: normal; overflow-wrap: anywhere; }
.bd-article code.download, .bd-article code.download span.pre { white-space: nowrap; overflow-wrap: normal; }
.bd-article pre { overflow-x: auto; max-width: 100%; }
.bd-article h1, .bd-article h2, .bd-article h3, .bd-article figcaption { overflow-wrap: anywhere; }
.bd-article img { max-width: 100%; height: auto; }
.bd-article figure { margin: 1rem 0; }
.bd-article figcaption { font-size: 0.9rem; text-align: left; }
table.verdicts { font-size: 0.75rem; border-collapse: collapse; line-height: 1.25; }
table.verdicts th, table.verdicts td { font-size: 0.75rem; padding: 0.15rem 0.25rem; text-align: center; overflow-wrap: normal; border: 1px solid #fff; }
table.verdicts th.claim { text-align: left; min-width: 10rem; max-width: 16rem; font-weight: normal; }
table.verdicts .prov { display: block; font-size: 0.65rem; color: #444; }
table.verdicts td a { display: block; color: inherit; text-decoration: none; }
.v-holds { background: #b7e4b0; } .v-does-not-hold { background: #f4b6b0; } .v-inconclusive { background: #fde9a9; }
.v-undecidable { background: #d9c8ef; } .v-not-testable { background: #dddddd; } .v-none { background: #ffffff; color: #999; }
.v-provisional { background-image: repeating-linear-gradient(135deg, transparent 0 6px, rgba(255,255,255,.55) 6px 9px); }
.site-footnote { font-size: 0.85rem; color: #555; }
details.provenance { margin-bottom: 1rem; font-size: 0.9rem; }
#the-paper-s-claims-cell-by-cell h3 { font-size: 1.1rem; }
#how-to-enable-uncertainty-estimation-in-ppo-reproduced > h1 { font-size: 2rem; }
"""
#: Search from a page opened as a file (file://, no server): Sphinx finds the pages from searchindex.js, then fetches
#: each hit's page for a summary, which the browser refuses for file:// URLs (a SEVERE console message per hit).
#: Opened as a file, hits are listed with their titles and no summary; served, with summaries as usual.
FILE_SEARCH_JS = ('if (window.location.protocol === "file:") { DOCUMENTATION_OPTIONS.SHOW_SEARCH_SUMMARY = false; }\n')
#: The site's icon: a square in the colour of a verdict that holds (no binary file in the repository).
FAVICON = ('<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 16 16"><rect width="16" height="16" rx="3" '
           'fill="#b7e4b0"/></svg>\n')


@dataclass(frozen=True)
class NotebookPage:
    """One executed notebook on the site, with where it comes from."""

    name: str  # file name, e.g. 03_ood_detection.ipynb
    executed: Path  # results/<profile>/notebooks/<name>, the file
    committed: str  # the same, relative to the repository root
    source: str  # notebooks/<name>, the notebook the stage executes
    stage: str  # the dvc.yaml stage that writes `executed`
    title: str  # its first heading

    @property
    def docname(self) -> str:
        return f"notebooks/{Path(self.name).stem}"


def active_profile(root: Path = ROOT) -> str:
    """The active profile of params.yaml, through the pipeline's one reader."""
    from paper_lib.pipeline.config import load_run_config

    return load_run_config(root / "params.yaml").profile


def executed_notebooks(profile: str, root: Path = ROOT) -> Path:
    """The folder of `profile`'s executed notebooks, results/<profile>/notebooks/ (paper_lib.pipeline.layout)."""
    from paper_lib.pipeline.layout import Layout

    return Layout.of(root, profile).notebooks


def notebook_stages(dvc_yaml: Path = ROOT / "dvc.yaml") -> dict[str, tuple[str, str]]:
    """{executed notebook file name: (stage name, source notebook)} for every dvc.yaml stage that writes one.

    Read from the stages' outputs (`results/${run.profile}/notebooks/<name>`) and commands (`notebook_run
    notebooks/<name>`), so the site names the stage that really makes each page. Per-run (foreach) stages such as
    `train` write one notebook per run, not a results page, and are left out.
    """
    stages = yaml.safe_load(dvc_yaml.read_text())["stages"]
    found: dict[str, tuple[str, str]] = {}
    for stage, body in stages.items():
        if "foreach" in body:
            continue
        cmd = body.get("cmd", "")
        cmd = " ".join(cmd) if isinstance(cmd, list) else str(cmd)
        ran = STAGE_CMD.search(cmd)
        for out in body.get("outs", []):
            path = next(iter(out)) if isinstance(out, dict) else str(out)
            match = EXECUTED_OUT.match(path)
            if match and ran:
                if match.group(1) in found:
                    raise ValueError(f"dvc.yaml: stages {found[match.group(1)][0]} and {stage} both write {path}")
                found[match.group(1)] = (stage, ran.group(1))
    return found


def notebook_pages(profile: str, root: Path = ROOT) -> list[NotebookPage]:
    """Every executed notebook of `profile`, in file-name order, with its stage; refuses one no stage writes."""
    import nbformat

    stages = notebook_stages(root / "dvc.yaml")
    pages = []
    folder = executed_notebooks(profile, root)
    for executed in sorted(folder.glob("*.ipynb")):
        if executed.name not in stages:
            raise ValueError(f"{executed.relative_to(root)}: no dvc.yaml stage writes it (its outs name "
                             f"results/${{run.profile}}/notebooks/{executed.name}); the site names the stage of "
                             "every page: add the stage or remove the stale copy")
        stage, source = stages[executed.name]
        nb = read_notebook(executed, stage, root)
        title = next((line[2:].strip() for cell in nb.cells if cell.cell_type == "markdown"
                      for line in cell.source.splitlines() if line.startswith("# ")), Path(executed.name).stem)
        pages.append(NotebookPage(executed.name, executed, executed.relative_to(root).as_posix(), source, stage, title))
    if not pages:
        raise ValueError(f"no executed notebook in {folder.relative_to(root)}/: `make reproduce` writes them")
    missing = sorted(set(stages) - {page.name for page in pages})
    if missing:  # a page left out would leave the previous build's copy of it on the site, stale
        where = (folder / missing[0]).relative_to(root)
        raise ValueError(f"{where} is missing (the DVC stage {stages[missing[0]][0]} writes it"
                         + (f"; {len(missing) - 1} more are missing too" if len(missing) > 1 else "")
                         + f"): run `dvc repro {stages[missing[0]][0]}` or restore the committed copy with "
                         f"`git checkout {where}`; the site was not built")
    return pages


def read_notebook(path: Path, stage: str, root: Path = ROOT):
    """An executed notebook, or one error naming it and its stage when it is truncated or not a notebook."""
    import nbformat

    try:
        return nbformat.read(path, as_version=4)
    except Exception as err:  # a truncated JSON file, or not a notebook: nbformat's errors vary by cause
        where = path.relative_to(root) if path.is_relative_to(root) else path
        raise ValueError(f"{where} is not a readable notebook (cut off?) ({type(err).__name__}: {err}); run `dvc repro "
                         f"{stage}` or restore the committed copy with `git checkout {where}`; the site was not "
                         "built") from None


def provenance_note(page: NotebookPage, profile: str) -> str:
    """The lines under a notebook page's title: which notebook, which committed copy, which DVC stage.

    Folded (an HTML <details>): its summary names the notebook and the stage at a glance, the rest is one click
    away, so the page opens with the notebook's own words rather than with where it comes from.
    """
    from html import escape

    def code(text: str) -> str:
        return f"<code>{escape(text)}</code>"

    return (f'<details class="provenance"><summary><strong>Where this page comes from:</strong> {code(page.source)}, '
            f"DVC stage <strong>{code(page.stage)}</strong></summary><p>The notebook {code(page.source)} as executed "
            f"for profile {code(profile)} by the DVC stage <strong>{code(page.stage)}</strong> "
            f"({code('dvc repro ' + page.stage)}; {code('make reproduce')} runs every table stage); its committed copy "
            f"is {code(page.committed)}. Nothing was executed to build this page. To run it yourself: "
            f"{code('make lab')}, then open {code(page.source)}.</p></details>\n")


@dataclass(frozen=True)
class DeclaredFigure:
    """One figure a notebook source declares (cell metadata `figures`): the committed PNG it shows and its words."""

    cell: int  # the source cell that draws it (code cells counted with the markdown ones, as nbformat lists them)
    file: Path  # results/<profile>/figures/..., the committed PNG
    caption: str
    alt: str
    paper: str  # the paper's figure (its LaTeX label or section) where it reproduces one, else ""
    pattern: str  # the declared glob: one of several figures where it has a wildcard


def declared_figures(source: Path, profile: str, root: Path = ROOT,
                     executed: Path | None = None) -> list[DeclaredFigure]:
    """The figures `source` (a notebook under notebooks/) declares, expanded against the committed figure files.

    Each code cell that draws figures says so in its metadata, `figures: [{files, caption, alt, paper}]`, `files`
    a glob under results/<profile>/figures/ (a loop over envs draws one figure per matching file). The declaration
    is read from the notebook's source, not its executed copy, so a figure missing from the executed copy (or from
    its page) is seen as missing: the site tests compare each page with this list. One exception, with `executed`
    given: a cell the executed copy never ran (its code is not in it: the source gained it since the last
    `make reproduce`) cannot have made its figure yet, and is left out until the pipeline runs it.
    """
    import json

    from paper_lib.pipeline.layout import Layout

    folder = Layout.of(root, profile).figures
    ran = None
    if executed is not None:
        ran = {"".join(cell["source"]) for cell in json.loads(executed.read_text(encoding="utf-8"))["cells"]
               if cell["cell_type"] == "code"}
    found = []
    for index, cell in enumerate(json.loads(source.read_text(encoding="utf-8"))["cells"]):
        for entry in cell.get("metadata", {}).get("figures", []):
            files = sorted(folder.glob(entry["files"]))
            if not files and ran is not None and "".join(cell["source"]) not in ran:
                print(f"site: {source.name} cell {index} is newer than its executed copy: its figures "
                      f"({entry['files']}) appear after `make reproduce`", file=sys.stderr)
                continue
            if not files:
                raise ValueError(f"{source.name} cell {index}: declares figures {entry['files']!r}, and no committed "
                                 f"file under {folder.relative_to(root)}/ matches")
            found += [DeclaredFigure(index, file, entry["caption"], entry["alt"], entry.get("paper", ""), entry["files"])
                      for file in files]
    return found


def figure_number(page: NotebookPage, index: int) -> str:
    """'Figure 3.2': the notebook's number, then the figure's place on its page (counted from 1)."""
    number = re.match(r"\d+", page.name)
    return f"Figure {int(number.group()) if number else page.name}.{index}"


def display_width(png: bytes) -> int:
    """The width in CSS px to show a PNG at: DISPLAY_SCALE of its pixel width (read from its IHDR header).

    Figures are drawn at 150 dpi: shown at half their pixel width, a 10 pt title is about 10 px high (readable) and
    a small figure is not blown up to the column's width; a wide one is capped by the column (CSS max-width).
    paper_lib.reporting.display holds the scale, and the fonts the figures are drawn with follow from it.
    """
    import struct

    from paper_lib.reporting.display import DISPLAY_SCALE

    if png[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    return round(struct.unpack(">I", png[16:20])[0] * DISPLAY_SCALE)


def full_size(site_path: str, docname: str) -> str:
    """The link from page `docname` to a file of files/ as the site serves it (html_extra_path: at the site root).

    A figure is shown at half its size; a click opens the PNG at full resolution, where every label is legible.
    """
    return posixpath.relpath(site_path.removeprefix("files/"), posixpath.dirname(docname) or ".")


#: The paper's figure numbers by LaTeX label, read once from its source (data/paper_figures.csv): a notebook declares
#: the label it reproduces (`fig:reward_graphs`), a reader wants the number printed in the PDF (Fig. 3).
PAPER_FIGURES = ROOT / "data" / "paper_figures.csv"
FIGURE_LABEL = re.compile(r"fig:[A-Za-z0-9_]+")


def paper_figure_numbers(path: Path = PAPER_FIGURES) -> dict[str, list[int]]:
    """label -> the paper's figure numbers with it (the paper reuses one label for Figs. 6-9), from the CSV."""
    import csv

    numbers: dict[str, list[int]] = {}
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            numbers.setdefault(row["label"], []).append(int(row["figure"]))
    return numbers


def paper_figure_names(text: str, numbers: dict[str, list[int]]) -> str:
    """Each LaTeX figure label in `text` as the paper's number: 'fig:reward_graphs' -> 'Fig. 3'; a label ending in
    '_' names the family it starts ('fig:mujoco_id_ood_examples_' -> 'Figs. 31, 32'); an unknown label stays."""
    def name(match: re.Match[str]) -> str:
        label = match.group(0)
        found = sorted({n for key, ns in numbers.items() for n in ns
                        if key == label or (label.endswith("_") and key.startswith(label))})
        if not found:
            return label
        return f"Fig. {found[0]}" if len(found) == 1 else "Figs. " + ", ".join(map(str, found))

    return FIGURE_LABEL.sub(name, text)


def figure_markdown(page: NotebookPage, index: int, figure: DeclaredFigure, site_path: str) -> str:
    """A MyST figure: number, caption, which paper figure it reproduces, alt text, and its PNG to download."""
    paper = f" Reproduces the paper's {paper_figure_names(figure.paper, paper_figure_numbers())}." if figure.paper else ""
    detail = f" ({figure.file.stem})" if any(char in figure.pattern for char in "*?[") else ""
    return (f"```{{figure}} /{site_path}\n:alt: {figure.alt}{detail}\n:name: {page.docname.replace('/', '-')}-figure-{index}\n"
            f":target: {full_size(site_path, page.docname)}\n"
            f":width: {display_width(figure.file.read_bytes())}px\n\n**{figure_number(page, index)}.**{detail} {figure.caption}{paper} "
            f"{{download}}`PNG </{site_path}>` (`{site_path.removeprefix('files/')}`)\n```\n")


#: A matplotlib Figure's repr, which a notebook prints when a cell ends with a figure: noise on a page.
FIGURE_REPR = re.compile(r"^<Figure size \d+x\d+ with \d+ Axes>$")
#: A Markdown table cell that holds pandas' NaN (not applicable or not run yet): shown as "-".
NAN_CELL = re.compile(r"(?<=\|)(\s*)NaN(\s*)(?=\|)")
NAN_NOTE = "<p class=\"site-footnote\">-: no value (not applicable to that env or method, or not run yet).</p>"


#: A DataFrame's HTML cell holding a float printed with pandas' 6 decimals (1433.220447).
LONG_FLOAT_CELL = re.compile(r"<td>(-?\d+\.\d{4,})</td>")


def short_number(value: float) -> str:
    """A float as the paper prints its numbers: whole above 100 (rewards), 2 decimals above 1, else 3 (AUROCs)."""
    size = abs(value)
    return f"{value:.0f}" if size >= 100 else f"{value:.2f}" if size >= 1 else f"{value:.3f}"


def round_html_cells(html: str) -> str:
    """A DataFrame's HTML with long floats shortened (short_number), the full value kept in the cell's title."""
    html = LONG_FLOAT_CELL.sub(lambda m: f'<td title="{m.group(1)}">{short_number(float(m.group(1)))}</td>', html)
    return re.sub(r"(<th[^>]*>)([^<]*)(</th>)", lambda m: m.group(1) + breakable(m.group(2)) + m.group(3), html)


ZWSP = "\u200b"


def breakable(text: str) -> str:
    """`text` (a table header, an env name) with places a line may break: before 'NoFrameskip', after '_'.

    An Atari env id or a snake_case column name is one long word that would set a column's width; a break there
    keeps the words whole ('Berzerk / NoFrameskip-v4'), never mid-word.
    """
    return text.replace("NoFrameskip", ZWSP + "NoFrameskip").replace("_", "_" + ZWSP)


def dash_nan_tables(text: str) -> str:
    """Markdown with every pipe table's NaN cells shown as "-", and a footnote under each table that has one.

    pandas writes NaN where a cell has no value (a measure an env lacks, a run not trained yet); 60 of 420 cells
    of the headline table read "NaN", which a reader takes for a failed computation.
    """
    out: list[str] = []
    replaced = False
    previous = ""
    fenced = False
    for line in text.splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        if line.startswith("|") and not fenced:
            header = not previous.startswith("|")
            shown = NAN_CELL.sub(lambda m: f"{m.group(1)}-{m.group(2)}", line)
            shown = (breakable(shown) if header and "](" not in shown
                     else shown.replace("NoFrameskip", ZWSP + "NoFrameskip"))
            previous = line
            replaced |= shown != line
            out.append(shown)
            continue
        previous = line
        if replaced:
            out += ["", NAN_NOTE]
            replaced = False
        out.append(line)
    if replaced:
        out += ["", NAN_NOTE]
    return "\n".join(out) + ("\n" if text.endswith("\n") else "")


def table_files(profile: str, root: Path = ROOT) -> dict[str, Path]:
    """{the Markdown text of a committed table: its file}: a table output on a page is matched to its CSV by text."""
    from paper_lib.pipeline.layout import Layout

    folder = Layout.of(root, profile).tables
    return {path.read_text(encoding="utf-8").strip(): path for path in sorted(folder.rglob("*.md"))}


def table_block(text: str) -> str:
    """The pipe table of a committed table's Markdown (its lines from the first starting with '|'), '' if none."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith("|")), None)
    if start is None:
        return ""
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    return "\n".join(lines[start:end])


def offer_csvs(text: str, tables: dict[str, Path], root: Path = ROOT) -> tuple[str, dict[str, bytes]]:
    """Markdown (a docs page) with a CSV link under each pasted committed table, and the CSVs by site path.

    docs/results.md and the README paste the committed tables (scripts/readme_results.py); a table is recognised
    by its rows, exactly as committed, so a hand-written table gets no link.
    """
    files: dict[str, bytes] = {}
    for committed, path in tables.items():
        block, csv = table_block(committed), path.with_suffix(".csv")
        if not block or not csv.is_file() or block + "\n" not in text + "\n":
            continue
        rel = csv.relative_to(root).as_posix()
        files["files/" + rel] = csv.read_bytes()
        text = (text + "\n").replace(block + "\n", f"{block}\n\n{{download}}`CSV </files/{rel}>` (`{rel}`)\n\n", 1)
    return text, files


def page_notebook(page: NotebookPage, profile: str, root: Path = ROOT) -> tuple[str, dict[str, bytes]]:
    """The executed notebook as its page shows it, and the files the page offers (PNG, CSV) by site path.

    The provenance note goes under the title; code is hidden behind a toggle (a reader wants the result, the code
    is one click away); each declared figure becomes a numbered figure with caption, alt text and its PNG; each
    table printed from a committed table file gets its CSV beside it, and NaN cells read "-" with a footnote; a
    matplotlib repr output is dropped. Outputs are otherwise untouched: no number is computed here.
    """
    import base64
    import hashlib

    import nbformat

    nb = read_notebook(page.executed, page.stage, root)
    nb.cells = [cell for cell in nb.cells if "injected-parameters" not in cell.get("metadata", {}).get("tags", [])]
    declared = declared_figures(root / page.source, profile, root, page.executed)
    by_hash = {hashlib.sha256(figure.file.read_bytes()).hexdigest(): figure for figure in declared}
    tables = table_files(profile, root)
    files: dict[str, bytes] = {}
    count = 0
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        cell.metadata.setdefault("tags", [])
        if "hide-input" not in cell.metadata["tags"]:
            cell.metadata["tags"].append("hide-input")
        outputs = []
        for out in cell.get("outputs", []):
            data = out.get("data", {})
            if set(data) == {"text/plain"} and FIGURE_REPR.match(data["text/plain"].strip()):
                continue
            if "image/png" in data:
                raw = base64.b64decode(data["image/png"])
                figure = by_hash.get(hashlib.sha256(raw).hexdigest())
                count += 1
                if figure is None:  # not declared by the source: shown, unnumbered, and counted by the tests
                    outputs.append(out)
                    continue
                site_path = "files/" + figure.file.relative_to(root).as_posix()
                files[site_path] = raw
                out = nbformat.v4.new_output("display_data", data={"text/markdown": figure_markdown(
                    page, count, figure, site_path)})
            elif "text/html" in data and "dataframe" in data["text/html"]:
                shown_html = fit_dataframe(round_html_cells(data["text/html"]))  # rounded, wrapped, split if wide
                out = nbformat.v4.new_output("display_data", data={**data, "text/html": shown_html})
            elif "text/markdown" in data and "|" in data["text/markdown"]:
                text = data["text/markdown"]
                committed = tables.get(text.strip())
                shown = dash_nan_tables(fit_tables(text))
                extra = ""
                if committed is not None and committed.with_suffix(".csv").is_file():
                    csv = committed.with_suffix(".csv")
                    site_path = "files/" + csv.relative_to(root).as_posix()
                    files[site_path] = csv.read_bytes()
                    extra += f"\n{{download}}`CSV </{site_path}>` (`{csv.relative_to(root).as_posix()}`)\n"
                out = nbformat.v4.new_output("display_data", data={"text/markdown": shown + extra})
            outputs.append(out)
        cell.outputs = outputs
    note = nbformat.v4.new_markdown_cell(provenance_note(page, profile))
    first = nb.cells[0] if nb.cells else None
    if first is not None and first.cell_type == "markdown" and first.source.startswith("# "):
        title, _, rest = first.source.partition("\n")
        first.source = title
        nb.cells[1:1] = [note] + ([nbformat.v4.new_markdown_cell(rest.strip("\n"))] if rest.strip() else [])
    else:
        nb.cells.insert(0, note)
    for cell in nb.cells:
        cell.pop("id", None)  # ids are not needed to render, and the committed copies carry none
    nb.nbformat_minor = 4
    return nbformat.writes(nb), files


#: The verdicts of notebook 6 (paper_lib/reporting/claims.py), as the matrix colours them; a verdict starts with
#: its kind ('inconclusive, provisional (3 of 5 seeds)').
VERDICT_KINDS = ("holds", "does not hold", "inconclusive", "undecidable", "not testable")
CLAIMS_DOC = "claims"
ARXIV = "https://arxiv.org/abs/2210.03649"


def verdict_kind(verdict: str) -> str:
    """The kind of a verdict of the claims table ('inconclusive, provisional (3 of 5 seeds)' -> 'inconclusive')."""
    head = verdict.split(",")[0].strip()  # 'undecidable at 5 seeds (needs about 10)' is of kind 'undecidable'
    kind = next((kind for kind in VERDICT_KINDS if head == kind or head.startswith((kind + " ", kind + "("))), None)
    if kind is None:
        raise ValueError(f"paper_claims.csv: verdict {verdict!r} is none of {VERDICT_KINDS}: the site colours each kind")
    return kind


def short_env(env: str) -> str:
    """An env's name as a column header: 'SpaceInvadersNoFrameskip-v4' -> 'SpaceInvaders' (the full name in its title)."""
    return re.sub(r"(NoFrameskip-v\d+|-v\d+)$", "", env)


def claim_anchor(index: int, env: str) -> str:
    """The id of one (claim, env) cell's evidence on the claims page."""
    return f"claim-{index}-" + re.sub(r"[^a-z0-9]+", "-", env.lower()).strip("-")


def read_claims(profile: str, root: Path = ROOT) -> "pd.DataFrame":
    """The committed claims table of notebook 6 (results/<profile>/tables/paper_claims.csv) as a DataFrame."""
    import pandas as pd
    from paper_lib.pipeline.layout import Layout

    path = Layout.of(root, profile).table("paper_claims", "csv")
    if not path.is_file():
        raise ValueError(f"{path.relative_to(root)} is missing: the home page opens with its verdicts "
                         "(`make reproduce` writes it)")
    return pd.read_csv(path, keep_default_na=False)


def verdict_matrix(claims: "pd.DataFrame") -> str:
    """The claims x envs matrix as an HTML table: one coloured cell per verdict, each a link to its evidence.

    Raw HTML (a MyST table cannot carry a class per cell): the colours say the verdict at a glance, the text says
    it too (colour is never the only cue), hatching marks a provisional verdict (an env short of its registered
    seeds). An env a claim is not checked in is an empty grey cell.
    """
    from html import escape

    envs = list(dict.fromkeys(claims["env"]))
    head = "".join(f'<th title="{escape(env)}">{escape(short_env(env))}</th>' for env in envs)
    rows = []
    for index, (claim, cells) in enumerate(claims.groupby("claim", sort=False), start=1):
        by_env = {row.env: row for row in cells.itertuples()}
        tds = []
        for env in envs:
            row = by_env.get(env)
            if row is None:
                tds.append('<td class="v-none" title="not checked in this env">&#8211;</td>')
                continue
            kind = verdict_kind(row.verdict)
            provisional = " v-provisional" if "provisional" in row.verdict else ""
            label = escape(kind) + ('<span class="prov">provisional</span>' if provisional else "")
            tds.append(f'<td class="v-{kind.replace(" ", "-")}{provisional}" title="{escape(row.verdict)}">'
                       f'<a href="{CLAIMS_DOC}.html#{claim_anchor(index, env)}">{label}</a></td>')
        rows.append(f'<tr><th class="claim">{escape(claim)}</th>{"".join(tds)}</tr>')
    legend = " ".join(f'<span class="v-{k.replace(" ", "-")}">&nbsp;{k}&nbsp;</span>' for k in VERDICT_KINDS)
    return ("```{raw} html\n<div id=\"verdicts\"><table class=\"verdicts\"><thead><tr><th class=\"claim\">claim</th>"
            f"{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>\n"
            f'<p class="site-footnote">{legend}; <span class="v-inconclusive v-provisional">&nbsp;hatched&nbsp;</span>: '
            "provisional (fewer seeds than registered). Each cell links to its evidence.</p></div>\n```\n")


def claims_page(claims: "pd.DataFrame", profile: str) -> str:
    """claims.md: every (claim, env) verdict with its evidence, the target of the matrix's links."""
    parts = ["# The paper's claims, cell by cell\n",
             f"Every verdict of the home page's matrix with its evidence, as notebook 6 wrote them to "
             f"`results/{profile}/tables/paper_claims.csv` (the rules: [the pre-registration](docs/preregistration.md)).\n"]
    for index, (claim, cells) in enumerate(claims.groupby("claim", sort=False), start=1):
        parts.append(f"## {claim}\n")
        for row in cells.itertuples():
            parts.append(f"({claim_anchor(index, row.env)})=\n### {row.env}: {row.verdict}\n\n{row.evidence}\n")
    return "\n".join(parts)


def claims_reading(claims: "pd.DataFrame") -> str:
    """A few sentences per claim, counted from the claims table: where it holds, fails, or is open, and why."""
    lines = []
    for claim, cells in claims.groupby("claim", sort=False):
        kinds = cells["verdict"].map(verdict_kind)
        counted = "; ".join(f"{kind} in {', '.join(map(short_env, cells['env'][kinds == kind]))}"
                            for kind in VERDICT_KINDS if (kinds == kind).any())
        provisional = int(cells["verdict"].str.contains("provisional").sum())
        lines.append(f"- **{claim}**: {counted}" + (f" ({provisional} of {len(cells)} provisional: fewer seeds than "
                                                     "registered)." if provisional else "."))
    return "\n".join(lines) + "\n"


def first_sentence(caption: str) -> str:
    """A table's one-line reading: its caption up to the first parenthesis, semicolon or full stop."""
    return re.split(r" \(|; |\. ", caption.strip(), maxsplit=1)[0].rstrip(".:") + "."


def table_rows(profile: str, shown: dict[str, str], root: Path = ROOT, titles: dict[str, str] | None = None) -> str:
    """Markdown rows: each committed table, its one-line reading, the page that shows it, its CSV."""
    rows = []
    for text, path in table_files(profile, root).items():
        csv = path.with_suffix(".csv")
        rel = csv.relative_to(root).as_posix()
        page = shown.get(rel)
        where = f"[{(titles or {}).get(page, page)}]({page}.ipynb)" if page else "[all tables](docs/results.md)"
        rows.append(f"| `{path.relative_to(tables_folder(profile, root)).with_suffix('').as_posix()}` | "
                    f"{first_sentence(text.splitlines()[0]).replace('|', '/')} | {where} | "
                    + (f"{{download}}`CSV </files/{rel}>`" if csv.is_file() else "") + " |")
    return "| table | what it says | shown on | CSV |\n|---|---|---|---|\n" + "\n".join(rows) + "\n"


def tables_folder(profile: str, root: Path) -> Path:
    """results/<profile>/tables/ (paper_lib.pipeline.layout)."""
    from paper_lib.pipeline.layout import Layout

    return Layout.of(root, profile).tables


#: The headline figure: notebook 3's AUROC per method and env with intervals; until the pipeline has drawn it (a
#: checkout whose executed notebook predates it), the AUROC performance profiles, saying so.
HEADLINE_FIGURES = (
    ("auroc_intervals.png",
     "AUROC of each member method's value and policy uncertainty on perturbed states, per env, with 95% intervals "
     "(notebook 3; dashed: chance). The verdicts above read the differences between methods, not these levels.",
     "Dot plot with error bars: AUROC of value_std and policy_std for each member method, one panel per env"),
    ("auroc_profiles.png",
     "No committed figure shows AUROC per method and env with intervals yet (notebook 3 draws it at the next "
     "`make reproduce`); the nearest is this one, notebook 3's performance profiles of AUROC per method (MuJoCo "
     "and Atari apart, 95% stratified-bootstrap bands). The per-env AUROC with its interval is in "
     "`tables/ood_metrics`.",
     "Performance profiles of AUROC on perturbed states: for each method, the share of runs whose AUROC exceeds "
     "each threshold, MuJoCo and Atari apart, with bootstrap bands"),
)


def headline_figure(profile: str, root: Path = ROOT) -> tuple[Path, str, str]:
    """(committed PNG, caption, alt text) of the home page's figure: the first of HEADLINE_FIGURES committed."""
    from paper_lib.pipeline.layout import Layout

    folder = Layout.of(root, profile).figures
    for name, caption, alt in HEADLINE_FIGURES:
        if (folder / name).is_file():
            return folder / name, caption, alt
    raise ValueError(f"none of {[name for name, _, _ in HEADLINE_FIGURES]} is committed in {folder.relative_to(root)}/: "
                     "the home page shows one (`make reproduce` draws them)")


def toctree(caption: str, docnames: list[str]) -> str:
    """A hidden toctree: the sidebar's group `caption`."""
    return "```{toctree}\n:hidden:\n:caption: " + caption + "\n\n" + "\n".join(docnames) + "\n```\n"


def home_page(profile: str, pages: list[NotebookPage], docs: list[str], claims: "pd.DataFrame", shown: dict[str, str],
              root: Path = ROOT) -> str:
    """index.md: the answer first (the verdict matrix, the headline figure, the reading), then every table, then the rest.

    A reader comes with one question (does Masksembles keep the reward and detect OOD better?): the matrix answers
    it in the first screen; everything below is the evidence, one click away.
    """
    from paper_lib.pipeline.layout import Layout

    figure, note, alt = headline_figure(profile, root)
    figure_rel = figure.relative_to(root).as_posix()
    rows = "\n".join(f"| [{page.title}]({page.docname}.ipynb) | `{page.source}` | `{page.stage}` |" for page in pages)
    manual = [d for d in MANUAL_FIRST if d in docs] + [d for d in docs if d not in
                                                          (*MANUAL_FIRST, *RESULTS_PAGES, *DEVIATIONS_AND_STUDY)]
    claims_csv = Layout.of(root, profile).table("paper_claims", "csv").relative_to(root).as_posix()
    return "\n".join([
        "# How to Enable Uncertainty Estimation in PPO, reproduced\n",
        f"Do the paper's claims ([arXiv 2210.03649]({ARXIV})) hold on our runs? One row per claim, one column per "
        f"env, from `{claims_csv}` ({{download}}`CSV </files/{claims_csv}>`; [every cell's evidence]({CLAIMS_DOC}.md)).\n",
        verdict_matrix(claims),
        f"```{{figure}} /files/{figure_rel}\n:alt: {alt}\n"
        f":name: headline-figure\n:target: {full_size('files/' + figure_rel, 'index')}\n:width: 100%\n\n**Headline figure.** {note} "
        f"{{download}}`PNG </files/{figure_rel}>` (`{figure_rel}`)\n```\n",
        "## What the verdicts say\n",
        "Counted from the claims table (one rule for every claim: holds when the 95% interval excludes failure, does "
        "not hold when it excludes success, otherwise inconclusive; the rules and seed plan: "
        "[the pre-registration](docs/preregistration.md)):\n",
        claims_reading(claims),
        "## Every table, in one line each\n",
        "Each committed table of `results/" + profile + "/tables/`, its first line of caption, the page that shows it "
        "and its CSV. All of them on one page: [every generated table](docs/results.md).\n",
        table_rows(profile, shown, root, {page.docname: page.title for page in pages}),
        "## The paper's tables and figures\n",
        "Every table and figure, as its notebook drew it, with its reading; where we depart from the paper: "
        "[Deviations](docs/deviations.md); the meta-optimization: [The study](docs/study.md).\n",
        "| page | notebook | DVC stage |\n|---|---|---|\n" + rows + "\n",
        "## How to cite\n",
        CITE_SECTION,
        toctree("Verdicts and every table", [CLAIMS_DOC] + [f"docs/{d}" for d in RESULTS_PAGES]),
        toctree("The paper's tables and figures", [page.docname for page in pages]),
        toctree("Deviations and the study", [f"docs/{d}" for d in DEVIATIONS_AND_STUDY]),
        toctree("Manual", ["README"] + [f"docs/{d}" for d in manual]),
    ])


#: How to cite: the paper, and this artifact (CITATION.cff at the repository root says the same).
CITE_SECTION = f"""The paper ([arXiv 2210.03649]({ARXIV})):

```bibtex
@article{{bykovets2022uncertainty,
  title   = {{How to Enable Uncertainty Estimation in Proximal Policy Optimization}},
  author  = {{Bykovets, Eugene and Metz, Yannick and El-Assady, Mennatallah and Keim, Daniel A. and Buhmann, Joachim M.}},
  journal = {{arXiv preprint arXiv:2210.03649}},
  year    = {{2022}},
  url     = {{{ARXIV}}}
}}
```

This artifact (the reproduction: `paper_lib`, the notebooks and the committed results; `CITATION.cff`, MIT licence,
`LICENSE`):

```bibtex
@software{{paper_lib_reproduction,
  title = {{paper\\_lib: How to Enable Uncertainty Estimation in Proximal Policy Optimization, reproduced}},
  note  = {{Reproducible artifact of arXiv:2210.03649; cite the commit named at the foot of each page}},
  year  = {{2026}}
}}
```
"""


def site_links(text: str, doc: str, sources: set[str], profile: str, root: Path = ROOT) -> str:
    """`text` (the Markdown of site source `doc`) with its links to repository files made to work on the site.

    A link to another page of the site stays. One to a committed executed notebook
    (`results/<profile>/notebooks/X.ipynb`) goes to that notebook's page. One to any other file that exists in the
    repository (code, a CSV, a folder) keeps its text and names the path, since the site holds no copy of it. A
    link to nothing stays as written, so Sphinx reports it (tests/project/test_site.py fails on any warning).
    """
    here = posixpath.dirname(doc)
    fenced = False
    lines = []
    for line in text.splitlines(keepends=True):
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        lines.append(line if fenced else MD_LINK.sub(lambda m: _site_link(m, here, sources, profile, root), line))
    return "".join(lines)


def _site_link(match: re.Match, here: str, sources: set[str], profile: str, root: Path) -> str:
    label, target = match.group(1), match.group(2)
    if re.match(r"^([a-z][a-z0-9+.-]*:|#|/)", target, re.IGNORECASE):
        return match.group(0)  # a URL, an anchor on the same page, an absolute path
    path, hash_, fragment = target.partition("#")
    rel = posixpath.normpath(posixpath.join(here, unquote(path)))
    if rel in sources or rel.startswith("../"):
        return match.group(0)
    folder = executed_notebooks(profile, Path(".")).as_posix()  # relative to the repository, as `rel`
    executed = re.fullmatch(rf"{re.escape(folder)}/([^/]+\.ipynb)", rel)
    if executed and f"notebooks/{executed.group(1)}" in sources:
        page = posixpath.relpath(f"notebooks/{executed.group(1)}", here or ".")
        return f"[{label}]({page}{hash_}{fragment})"
    if (root / rel).exists():
        shown = f"`{rel}`"
        return shown if label.strip("`") == rel or label.strip("`") == path else f"{label} ({shown})"
    return match.group(0)


def write_if_changed(path: Path, content: str | bytes) -> None:
    """Write `content` unless the file holds it already (Sphinx re-reads only what changed)."""
    data = content.encode("utf-8") if isinstance(content, str) else content
    if path.is_file() and path.read_bytes() == data:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def assemble(source_dir: Path = SOURCE_DIR, root: Path = ROOT, site_dir: Path = SITE_DIR) -> list[NotebookPage]:
    """Lay out the site's sources in `source_dir` from docs/, README.md and the executed notebooks.

    A page whose source left is removed from `site_dir` too: Sphinx builds only the pages it has, and would keep
    the previous build's copy of a removed one on the site."""
    profile = active_profile(root)
    pages = notebook_pages(profile, root)
    docs = sorted(p.stem for p in (root / "docs").glob("*.md"))
    missing = [d for d in (*RESULTS_PAGES, *DEVIATIONS_AND_STUDY) if d not in docs]
    if missing:
        raise ValueError(f"docs/ lacks {missing}: the site's first groups show them")
    readme = (root / "README.md").read_text(encoding="utf-8")
    markdown = {"README.md": readme, **{f"docs/{d}.md": (root / "docs" / f"{d}.md").read_text(encoding="utf-8")
                                        for d in docs}}
    sources = {*markdown, "index.md", f"{CLAIMS_DOC}.md", *(f"{page.docname}.ipynb" for page in pages)}
    wanted: dict[str, str | bytes] = {
        "conf.py": CONF_PY.format(project="paper_lib", title="Uncertainty estimation in PPO, reproduced",
                                  footer=footer(root), secondary=secondary_sidebars(pages)),
        "_static/results.css": RESULTS_CSS,
        "_static/favicon.svg": FAVICON,
        "_static/file_search.js": FILE_SEARCH_JS,
    }
    tables = table_files(profile, root)
    for rel, text in markdown.items():
        text, offered = offer_csvs(text, tables, root)
        wanted[rel] = dash_nan_tables(fit_tables(site_links(text, rel, sources, profile, root)))
        wanted.update(offered)
    shown: dict[str, str] = {}  # committed CSV -> the page that shows its table
    for page in pages:
        wanted[f"{page.docname}.ipynb"], offered = page_notebook(page, profile, root)
        wanted.update(offered)
        shown.update({rel.removeprefix("files/"): page.docname for rel in offered if rel.endswith(".csv")})
    claims = read_claims(profile, root)
    home = home_page(profile, pages, docs, claims, shown, root)
    wanted["index.md"] = site_links(home, "index.md", sources, profile, root)
    wanted[f"{CLAIMS_DOC}.md"] = site_links(claims_page(claims, profile), f"{CLAIMS_DOC}.md", sources, profile, root)
    from paper_lib.pipeline.layout import Layout

    layout = Layout.of(root, profile)
    for path in (headline_figure(profile, root)[0], layout.table("paper_claims", "csv"),
                 *(csv for csv in (p.with_suffix(".csv") for p in table_files(profile, root).values()) if csv.is_file())):
        wanted["files/" + path.relative_to(root).as_posix()] = path.read_bytes()
    for rel, text in wanted.items():
        write_if_changed(source_dir / rel, text)
    for path in sorted(source_dir.rglob("*"), reverse=True):  # a page that left the repo leaves the site
        rel = path.relative_to(source_dir).as_posix()
        if path.is_file() and rel not in wanted:
            path.unlink()
            (site_dir / Path(rel).with_suffix(".html")).unlink(missing_ok=True)
        elif path.is_dir() and not any(path.iterdir()):
            path.rmdir()
    return pages


def secondary_sidebars(pages: list[NotebookPage]) -> dict[str, list[str]]:
    """The theme's right-hand column per page: the page's contents, except where wide results need the width.

    Named page by page: the theme refuses a page that two wildcard patterns match.
    """
    return {"**": ["page-toc"], "index": [], "README": [], "docs/results": [], **{page.docname: [] for page in pages}}


def commit(root: Path = ROOT) -> str:
    """The commit the site is built from ('+ local changes' where tracked files differ from it), or 'unknown'."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, check=True).stdout.strip()

    try:
        head = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head + (" + local changes" if dirty else "")


def footer(root: Path = ROOT) -> str:
    """Every page's foot: the commit it was built from, the paper, how to cite and the licence."""
    return (f'Built from commit <code class="site-commit">{commit(root)}</code> by <code>make site</code>. '
            f'Paper: <a href="{ARXIV}">arXiv 2210.03649</a>. Cite: the home page\'s "How to cite" and '
            "<code>CITATION.cff</code>; code under the MIT licence (<code>LICENSE</code>).")


def build(source_dir: Path = SOURCE_DIR, site_dir: Path = SITE_DIR, doctrees: Path = DOCTREES,
          warnings_file: Path = WARNINGS_FILE, quiet: bool = True) -> Path:
    """Run Sphinx on `source_dir` into `site_dir`; return its index.html (warnings go to `warnings_file`)."""
    cmd = [sys.executable, "-m", "sphinx", "-b", "html", "-j", "auto", "-d", str(doctrees), "-w", str(warnings_file),
           *(["-q"] if quiet else []), str(source_dir), str(site_dir)]
    subprocess.run(cmd, check=True, cwd=source_dir)
    return site_dir / "index.html"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clean", action="store_true", help="rebuild every page (drop build/site and its cache)")
    args = parser.parse_args(argv)
    start = time.monotonic()
    if args.clean:
        for path in (SITE_DIR, DOCTREES):
            shutil.rmtree(path, ignore_errors=True)
    pages = assemble()
    index = build()
    warnings = WARNINGS_FILE.read_text().count("WARNING") if WARNINGS_FILE.is_file() else 0
    print(f"site: {len(pages)} notebook pages and the docs in {time.monotonic() - start:.0f} s; open {index}"
          f" (or serve it, for search hits with summaries: .venv/bin/python -m http.server -d "
          f"{SITE_DIR.relative_to(ROOT)}); "
          f"{warnings} Sphinx warnings in {WARNINGS_FILE.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
