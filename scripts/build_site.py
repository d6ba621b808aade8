"""Build the results website (`make site`): docs/ and the executed notebooks as static HTML, offline.

    .venv/bin/python scripts/build_site.py          # build/site/index.html

Sphinx with myst-nb and sphinx-book-theme. Nothing is fetched and no notebook is executed: the pages show the
committed executed notebooks of the active profile (`results/<profile>/notebooks/`) as they are, so the site is
the committed results, never a fresh computation. The sources are assembled in `build/site-src/` (nothing is
written into docs/ or results/), laid out as the repository is (README.md, docs/*.md, notebooks/*.ipynb), so the
docs' links between each other, to the README and to the notebooks resolve on the site as they do on disk (a link
to a committed executed notebook goes to its page; one to any other repository file names the path):

- the home page: the README's headline table first, then one line per executed notebook (the paper's tables and
  figures with their reading), each naming its notebook and the DVC stage that made it;
- one page per executed notebook, headed by where it comes from (notebook, committed copy, DVC stage, read
  from dvc.yaml: never typed by hand);
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
from urllib.parse import unquote

import yaml

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
#: The README section that opens the home page (from its heading to the next `## ` heading).
HEADLINE_HEADING = "## Headline result"
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
                      "show_toc_level": 2}}
html_static_path = ["_static"]
html_css_files = ["results.css"]
html_copy_source = False  # the sources are in the repository; copying multi-MB notebooks again is waste
html_show_sourcelink = False
html_last_updated_fmt = None
suppress_warnings = ["myst.header"]  # docs/results.md's pasted tables sit under H3 headings below its H1, as on GitHub
'''


#: The results are wide tables: the page uses the window's width, and a number never breaks across lines (a table
#: wider than the page scrolls sideways).
RESULTS_CSS = """.bd-page-width { max-width: 120rem; }
.bd-main .bd-content .bd-article-container { max-width: 100%; }
.cell_output table td, .cell_output table th, section#results table td { white-space: nowrap; }
"""


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
    """The lines under a notebook page's title: which notebook, which committed copy, which DVC stage."""
    return (f"> **Where this page comes from.** The notebook `{page.source}` as executed "
            f"for profile `{profile}` by the DVC stage **`{page.stage}`** (`dvc repro {page.stage}`; `make reproduce` "
            f"runs every table stage); its committed copy is `{page.committed}`. "
            "Nothing was executed to build this page. To run it yourself: `make lab`, then open "
            f"`{page.source}`.\n")


def page_notebook(page: NotebookPage, profile: str) -> str:
    """The executed notebook with the provenance note right under its title (outputs untouched)."""
    import nbformat

    nb = read_notebook(page.executed, page.stage)
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
    return nbformat.writes(nb)


def headline_section(readme: str) -> str:
    """The README's headline section (its heading, reading and table), which opens the home page."""
    start = readme.find(HEADLINE_HEADING)
    if start < 0:
        raise ValueError(f"README.md has no '{HEADLINE_HEADING}' section: the home page opens with it")
    end = readme.find("\n## ", start + 1)
    return readme[start:end if end > 0 else len(readme)].strip() + "\n"


def toctree(caption: str, docnames: list[str]) -> str:
    """A hidden toctree: the sidebar's group `caption`."""
    return "```{toctree}\n:hidden:\n:caption: " + caption + "\n\n" + "\n".join(docnames) + "\n```\n"


def home_page(profile: str, pages: list[NotebookPage], docs: list[str], readme: str) -> str:
    """index.md: the headline results first, then every table and figure page, then the rest."""
    rows = "\n".join(f"| [{page.title}]({page.docname}.ipynb) | `{page.source}` | `{page.stage}` |" for page in pages)
    manual = [d for d in MANUAL_FIRST if d in docs] + [d for d in docs if d not in
                                                          (*MANUAL_FIRST, *RESULTS_PAGES, *DEVIATIONS_AND_STUDY)]
    return "\n".join([
        "# How to Enable Uncertainty Estimation in PPO, reproduced\n",
        "The results of this repository's reproduction of *How to Enable Uncertainty Estimation in Proximal Policy "
        f"Optimization* (arXiv 2210.03649), profile `{profile}`: the committed tables and the executed notebooks of "
        f"`results/{profile}/`, built into this site by `make site` (nothing here was computed for the site). "
        "To run a notebook yourself: `make lab`.\n",
        headline_section(readme),
        "## The paper's tables and figures\n",
        "Every table and figure, as its notebook drew it, with its reading; [every generated table](docs/results.md) "
        "on one page; where we depart from the paper: [Deviations](docs/deviations.md); the meta-optimization: "
        "[The study](docs/study.md).\n",
        "| page | notebook | DVC stage |\n|---|---|---|\n" + rows + "\n",
        toctree("Results", [f"docs/{d}" for d in RESULTS_PAGES]),
        toctree("The paper's tables and figures", [page.docname for page in pages]),
        toctree("Deviations and the study", [f"docs/{d}" for d in DEVIATIONS_AND_STUDY]),
        toctree("Manual", ["README"] + [f"docs/{d}" for d in manual]),
    ])


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


def write_if_changed(path: Path, text: str) -> None:
    """Write `text` unless the file holds it already (Sphinx re-reads only what changed)."""
    if path.is_file() and path.read_text(encoding="utf-8") == text:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


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
    sources = {*markdown, "index.md", *(f"{page.docname}.ipynb" for page in pages)}
    wanted = {
        "conf.py": CONF_PY.format(project="paper_lib", title="Uncertainty estimation in PPO, reproduced"),
        "_static/results.css": RESULTS_CSS,
        "index.md": site_links(home_page(profile, pages, docs, readme), "index.md", sources, profile, root),
        **{rel: site_links(text, rel, sources, profile, root) for rel, text in markdown.items()},
        **{f"{page.docname}.ipynb": page_notebook(page, profile) for page in pages},
    }
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
          f" (or serve it: .venv/bin/python -m http.server -d {SITE_DIR.relative_to(ROOT)}); "
          f"{warnings} Sphinx warnings in {WARNINGS_FILE.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
