"""The results website (`make site`, scripts/build_site.py), built from the committed files and read in a real browser.

The site is built once per module into tmp folders (the same code `make site` runs), served on a free local port,
and walked in headless chromium: every page loads, every image loads, every internal link (and its #anchor)
resolves, nothing is fetched from outside the site, and Sphinx's search finds a method name.

What a reader sees is checked in the browser too, not in the HTML: each page shows a minimum of visible text and
height, no page scrolls sideways at 1400 px or 400 px, no table scrolls sideways inside its own box at 1400 px, each page shows the figures its notebook's *source* declares
(not its executed copy, which could have lost one), the console has no SEVERE message, and the home page's verdict
matrix is whole inside the first screen at 1400 px. Mutation tests show these checks see what they claim to: a
stylesheet that blanks every page, one that keeps every table cell on one line, and an executed notebook that lost
a figure, all fail them.
"""

from __future__ import annotations

import functools
import http.server
import re
import shutil
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote, urldefrag, urlparse

import nbformat
import pytest

from _browser import headless_chromium, keep_screenshot, require_browser, wait_for

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

import build_site as project_site  # noqa: E402

#: The budget of one full build from the committed files ("about a minute" on an idle machine; CI's 2 cores are
#: shared with the other test worker, hence the margin).
BUILD_BUDGET_S = 300


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict:
    """A full build into tmp folders: sources, site, doctrees, warnings; with its pages and duration."""
    base = tmp_path_factory.mktemp("site")
    start = time.monotonic()
    pages = project_site.assemble(base / "src")
    index = project_site.build(base / "src", base / "site", base / "doctrees", base / "warnings.txt")
    return {"pages": pages, "index": index, "site": base / "site", "src": base / "src",
            "warnings": (base / "warnings.txt").read_text(), "seconds": time.monotonic() - start}


@pytest.fixture(scope="module")
def served(built) -> Iterator[str]:
    """The built site on a free local port (as `python -m http.server` serves it); yields its base URL."""
    handler = functools.partial(_QuietHandler, directory=str(built["site"]))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args) -> None:  # noqa: A002 (the base class's name)
        pass


def test_notebook_stages_come_from_dvc_yaml():
    """Each executed notebook is mapped to the stage whose outs write it and whose command runs its source."""
    stages = project_site.notebook_stages()
    assert stages["03_ood_detection.ipynb"] == ("ood", "notebooks/03_ood_detection.ipynb")
    assert stages["00_quickstart.ipynb"] == ("quickstart", "notebooks/00_quickstart.ipynb")
    assert stages["09_study.ipynb"][1] == "notebooks/09_study.ipynb"
    assert all(source == f"notebooks/{name}" for name, (_, source) in stages.items())


def test_a_notebook_no_stage_writes_is_refused(tmp_path):
    """An executed copy without a stage would be a page naming no stage: the build refuses it, naming the file."""
    (tmp_path / "results" / "p" / "notebooks").mkdir(parents=True)
    (tmp_path / "dvc.yaml").write_text((ROOT / "dvc.yaml").read_text())
    nbformat.write(nbformat.v4.new_notebook(), tmp_path / "results" / "p" / "notebooks" / "99_orphan.ipynb")
    with pytest.raises(ValueError, match="99_orphan.ipynb: no dvc.yaml stage writes it"):
        project_site.notebook_pages("p", tmp_path)


def test_links_to_repository_files_are_made_to_work_on_the_site():
    """Docs link to pages, to committed notebooks and to code: each becomes a page link or a named path."""
    text = ("[the reader](../paper_lib/pipeline/config.py), [Table 2](../results/paper/notebooks/03_ood_detection.ipynb#x), "
            "[runs](results.md#runs), [web](https://example.org), [gone](../nothere.py)\n"
            "```\n[kept](../paper_lib/pipeline/config.py)\n```\n")
    sources = {"docs/results.md", "docs/x.md", "notebooks/03_ood_detection.ipynb"}
    assert project_site.site_links(text, "docs/x.md", sources, "paper") == (
        "the reader (`paper_lib/pipeline/config.py`), [Table 2](../notebooks/03_ood_detection.ipynb#x), "
        "[runs](results.md#runs), [web](https://example.org), [gone](../nothere.py)\n"
        "```\n[kept](../paper_lib/pipeline/config.py)\n```\n")


def test_every_committed_table_has_its_own_one_line_reading():
    """The home page lists every table by its caption's first phrase: two tables that share it look like one."""
    readings: dict[str, list[str]] = {}
    for text, path in project_site.table_files("paper", project_site.ROOT).items():
        readings.setdefault(project_site.first_sentence(text.splitlines()[0]), []).append(path.name)
    assert {reading: names for reading, names in readings.items() if len(names) > 1} == {}


def test_the_site_builds_offline_within_budget(built):
    profile = project_site.active_profile()
    executed = sorted(p.name for p in (ROOT / "results" / profile / "notebooks").glob("*.ipynb"))
    assert [page.name for page in built["pages"]] == executed
    assert built["index"].is_file()
    assert built["seconds"] < BUILD_BUDGET_S, f"the site took {built['seconds']:.0f} s to build"
    assert "WARNING" not in built["warnings"], built["warnings"]
    print(f"site built in {built['seconds']:.0f} s")


def test_home_page_opens_with_the_verdicts_then_figure_reading_tables_and_pages(built):
    """The answer first: the verdict matrix, the headline figure, the reading, one line per table, then the pages."""
    home = (built["src"] / "index.md").read_text()
    order = [home.index(mark) for mark in ('<div id="verdicts">', ":name: headline-figure", "## What the verdicts say",
                                            "## Every table, in one line each", "## The paper's tables and figures")]
    assert order == sorted(order)
    claims = project_site.read_claims(project_site.active_profile())
    assert home.count('<td class="v-') == len(claims) + home.count('<td class="v-none"')
    for page in built["pages"]:
        assert f"| `{page.source}` | `{page.stage}` |" in home
    for doc in ("docs/results", "docs/deviations", "docs/study"):
        assert f"\n{doc}\n" in home


def _page_urls(site: Path, base: str) -> list[str]:
    """Every page of the site (the theme's template fragments under _static/ are not pages)."""
    return [base + p.relative_to(site).as_posix() for p in sorted(site.rglob("*.html")) if "_static" not in p.parts]


def test_every_page_image_and_internal_link_in_the_browser(built, served, tmp_path):
    """Every page loads with every image; every internal link and anchor resolves; nothing comes from outside."""
    require_browser()
    site, base = built["site"], served
    urls = _page_urls(site, base)
    ids: dict[str, set[str]] = {}
    links: dict[str, list[str]] = {}
    problems: list[str] = []
    with headless_chromium() as driver:
        for url in urls:
            driver.get(url)
            wait_for(lambda: driver.execute_script("return document.readyState") == "complete", 60, f"{url} to load")
            wait_for(lambda: driver.execute_script(
                "return Array.from(document.images).every(i => i.complete)"), 60, f"the images of {url}")
            state = driver.execute_script("""
                return {
                  title: document.title,
                  article: document.querySelector('article, [role=main]') !== null,
                  broken: Array.from(document.images).filter(i => !(i.naturalWidth > 0)).map(i => i.getAttribute('src')),
                  images: document.images.length,
                  ids: Array.from(document.querySelectorAll('[id]')).map(e => e.id),
                  links: Array.from(document.querySelectorAll('a[href]')).map(a => a.href),
                  resources: performance.getEntriesByType('resource').map(r => r.name),
                };""")
            page = urlparse(url).path
            ids[page] = set(state["ids"])
            links[page] = state["links"]
            if not state["article"] or "404" in state["title"]:
                problems.append(f"{page}: no page content (title {state['title']!r})")
            problems += [f"{page}: image {src} did not load" for src in state["broken"]]
            problems += [f"{page}: fetches {r} from outside the site" for r in state["resources"]
                         if not r.startswith(base)]
            if page.endswith("/notebooks/03_ood_detection.html"):
                assert state["images"] > 0, "the OOD detection page shows no figure"
                driver.execute_script("document.querySelector('.cell_output img').scrollIntoView()")
                keep_screenshot(driver, tmp_path, "site_notebook.png")
        driver.get(base + "index.html")
        keep_screenshot(driver, tmp_path, "site_home.png")
    for page, hrefs in links.items():
        for href in hrefs:
            target, fragment = urldefrag(href)
            if not target.startswith(base):
                continue  # an outside link (none is fetched: checked above)
            path = urlparse(target).path
            path = path + "index.html" if path.endswith("/") else path
            if not (site / unquote(path).lstrip("/")).is_file():
                problems.append(f"{page}: link to {href}: no such file on the site")
            elif fragment and path.endswith(".html") and path in ids and unquote(fragment) not in ids[path]:
                problems.append(f"{page}: link to {href}: no #{fragment} on that page")
    assert not problems, "\n".join(problems)
    assert len(urls) >= len(built["pages"]) + 3


#: The separator row of a Markdown pipe table (one per table): |---|:---|---:|
TABLE_SEPARATOR = re.compile(r"^\|(\s*:?-+:?\s*\|)+\s*$", re.MULTILINE)


def test_each_notebook_page_names_its_notebook_and_stage_and_shows_its_tables_and_figures(built):
    """Every figure (PNG output) and every table (Markdown or HTML output) of the executed notebook is on its page."""
    for page in built["pages"]:
        html = (built["site"] / f"{page.docname}.html").read_text()
        stage = f"<strong><code>{page.stage}</code></strong>"
        assert page.source in html and stage in html, f"{page.name}: its page does not name {page.source} and {page.stage}"
        outputs = [out.get("data", {}) for cell in nbformat.read(page.executed, as_version=4).cells
                   if cell.cell_type == "code" for out in cell.outputs]
        figures = sum("image/png" in data for data in outputs)
        tables = sum(len(TABLE_SEPARATOR.findall(data.get("text/markdown", ""))) or data.get("text/html", "").count("<table")
                     for data in outputs)
        assert html.count("<img") >= figures, f"{page.name}: {figures} figures in the notebook, fewer on its page"
        assert html.count("<table") >= tables, f"{page.name}: {tables} tables in the notebook, fewer on its page"


def test_search_finds_a_method_name(built, served, tmp_path):
    require_browser()
    with headless_chromium() as driver:
        driver.get(served + "search.html?q=Masksembles")
        summary = wait_for(lambda: driver.execute_script(  # Sphinx lists hits one by one, then says it finished
            "const s = document.querySelector('#search-results .search-summary'); "
            "return s && s.textContent.startsWith('Search finished') ? s.textContent : null"),
            60, "Sphinx's search to finish for Masksembles")
        hits = driver.execute_script(
            "return Array.from(document.querySelectorAll('#search-results ul.search li a')).map(a => a.href)")
        keep_screenshot(driver, tmp_path, "site_search.png")
    assert "found" in summary and any(urlparse(href).path.endswith("/docs/methods.html") for href in hits), (summary, hits)


def test_search_works_from_a_page_opened_as_a_file(built, tmp_path):
    """Opened as build/site/index.html (file://, no server), search finds a method name with a quiet console."""
    require_browser()
    with headless_chromium() as driver:
        driver.get((built["site"] / "search.html").as_uri() + "?q=Masksembles")
        summary = wait_for(lambda: driver.execute_script(
            "const s = document.querySelector('#search-results .search-summary'); "
            "return s && s.textContent.startsWith('Search finished') ? s.textContent : null"),
            60, "Sphinx's search to finish for Masksembles from file://")
        time.sleep(1)  # a summary fetch refused by the browser logs after the count is shown
        hits = driver.execute_script(
            "return Array.from(document.querySelectorAll('#search-results ul.search li a')).map(a => a.href)")
        severe = [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]
    assert "found" in summary and any(href.endswith("/docs/methods.html") for href in hits), (summary, hits)
    assert not severe, severe[:3]


#: Pages with little text by design: Sphinx's index of terms and the search page before a query.
SPARSE_PAGES = ("genindex.html", "search.html")
#: What a page must show to count as read: characters of visible text in its article, and its article's height.
MIN_TEXT_CHARS = 300
MIN_HEIGHT_PX = 400
#: The window width from which every table fits its column (no sideways scroll inside its box): a desktop's 1400 px.
#: Narrower (a phone's 400 px) a wide table scrolls inside its box, never the page.
TABLES_FIT_AT = 1400
#: What the reader sees of one page, measured in the browser (visibility and layout, not the HTML's content).
READER_JS = """
const article = document.querySelector('.bd-article');
const seen = article && article.checkVisibility({checkOpacity: true, checkVisibilityCSS: true});
const figures = seen ? Array.from(article.querySelectorAll('img')).filter(i => {
  const box = i.getBoundingClientRect();
  return box.width > 50 && box.height > 50 && i.checkVisibility({checkOpacity: true, checkVisibilityCSS: true});
}) : [];
// Each table's sideways scroll inside its own box: the table's, or a wrapper's that holds it alone (the theme's
// .pst-scrollable-table-container, a DataFrame's <div>), in px; with the table's first header cells, to name it.
const tables = seen ? Array.from(article.querySelectorAll('table')).map(t => {
  let over = 0;
  for (let e = t; e && e !== article && (e === t || e.querySelectorAll('table').length === 1); e = e.parentElement)
    over = Math.max(over, e.scrollWidth - e.clientWidth);
  const head = t.querySelector('tr');
  const name = head ? head.innerText.replace(/[\\u200b\\u2060]/g, '').replace(/\\s+/g, ' ').trim() : '';
  return {over, head: name.slice(0, 60)};
}) : [];
const matrix = document.querySelector('#verdicts table');
const headline = document.querySelector('#headline-figure img');
const box = matrix ? matrix.getBoundingClientRect() : null;
return {
  text: seen ? article.innerText.trim().length : 0,
  height: seen ? article.getBoundingClientRect().height : 0,
  sideways: document.documentElement.scrollWidth - document.documentElement.clientWidth,
  figures: figures.length,
  tables,
  matrix: box && {bottom: box.bottom, viewport: window.innerHeight, hidden: matrix.scrollWidth - matrix.clientWidth,
                  cells: matrix.querySelectorAll('td a').length,
                  figure: headline ? window.innerHeight - headline.getBoundingClientRect().top : null},
};"""


def expected_figures(built: dict) -> dict[str, int]:
    """{page path: the figures it must show}: each notebook page, what its source notebook declares; the home page, 1."""
    profile = project_site.active_profile()
    counts = {f"/{page.docname}.html": len(project_site.declared_figures(ROOT / page.source, profile, ROOT, page.executed))
              for page in built["pages"]}
    return {**counts, "/index.html": 1}


def reader_problems(driver, url: str, figures: int | None, css: str = "") -> list[str]:
    """What a reader would miss on `url` at the window's current width (`css`: a stylesheet injected first).

    Too little visible text or height (a blank page), sideways scrolling of the whole page, from TABLES_FIT_AT px a
    table that scrolls sideways inside its box, a figure count other than `figures` (None: not checked), a SEVERE
    console message.
    """
    driver.get(url)
    wait_for(lambda: driver.execute_script("return document.readyState") == "complete", 60, f"{url} to load")
    if css:
        driver.execute_script("const s = document.createElement('style'); s.textContent = arguments[0]; "
                              "document.head.appendChild(s);", css)
    seen = driver.execute_script(READER_JS)
    width = driver.execute_script("return window.innerWidth")
    page = urlparse(url).path
    problems = []
    if not page.endswith(SPARSE_PAGES) and (seen["text"] < MIN_TEXT_CHARS or seen["height"] < MIN_HEIGHT_PX):
        problems.append(f"{page} at {width} px: {seen['text']} characters of visible text, {seen['height']:.0f} px "
                        f"high (at least {MIN_TEXT_CHARS} and {MIN_HEIGHT_PX})")
    if seen["sideways"] > 0:
        problems.append(f"{page} at {width} px: the page scrolls {seen['sideways']} px sideways")
    if width >= TABLES_FIT_AT:
        problems += [f"{page} at {width} px: table {n} ({table['head']}) scrolls {table['over']} px sideways in its box"
                     for n, table in enumerate(seen["tables"], start=1) if table["over"] > 0]
    if figures is not None and seen["figures"] != figures:
        problems.append(f"{page} at {width} px: {seen['figures']} figures shown, its notebook declares {figures}")
    problems += [f"{page}: console {entry['level']}: {entry['message']}" for entry in driver.get_log("browser")
                 if entry["level"] == "SEVERE"]
    return problems


def test_every_page_shows_a_reader_its_text_and_figures_without_sideways_scroll(built, served, tmp_path):
    """At 1400 px and at 400 px: visible text and height, no page-level sideways scroll, the declared figures, a quiet
    console; at 1400 px no table scrolls sideways inside its box either (issue 68: 10 of 73 did)."""
    require_browser()
    urls = _page_urls(built["site"], served)
    figures = expected_figures(built)
    problems: list[str] = []
    with headless_chromium() as driver:
        for width in (1400, 400):
            driver.set_window_size(width, 1000)
            for url in urls:
                problems += reader_problems(driver, url, figures.get(urlparse(url).path))
            driver.get(served + "index.html")
            keep_screenshot(driver, tmp_path, f"site_home_{width}.png")
    assert not problems, "\n".join(problems)


def test_the_verdict_matrix_is_whole_in_the_first_screen(built, served, tmp_path):
    """At 1400 x 1000 the matrix ends above the fold, shows every column without scrolling, one link per verdict;
    the headline figure begins in the same screen."""
    require_browser()
    claims = project_site.read_claims(project_site.active_profile())
    with headless_chromium(1400, 1000) as driver:
        driver.get(served + "index.html")
        matrix = driver.execute_script(READER_JS)["matrix"]
        keep_screenshot(driver, tmp_path, "site_verdicts.png")
    assert matrix, "the home page has no verdict matrix (#verdicts table)"
    assert matrix["bottom"] <= matrix["viewport"], f"the matrix ends at {matrix['bottom']:.0f} px, below the first screen"
    assert matrix["hidden"] <= 0, f"{matrix['hidden']} px of the matrix are scrolled out of sight"
    assert matrix["cells"] == len(claims), f"{matrix['cells']} verdict links for {len(claims)} claim rows"
    assert matrix["figure"] is not None and matrix["figure"] >= 150, (
        f"the headline figure shows {matrix['figure']} px in the first screen (at least 150)")


def test_a_blank_page_fails_the_reader_checks(built, served):
    """Mutation: `.bd-article{display:none}` (every page blank, which the link and image walk passes) fails them."""
    require_browser()
    figures = expected_figures(built)
    with headless_chromium() as driver:
        for page in ("index.html", "notebooks/03_ood_detection.html", "docs/results.html"):
            problems = reader_problems(driver, served + page, figures.get(f"/{page}"), css=".bd-article{display:none}")
            assert any("visible text" in p for p in problems), (page, problems)


def test_tables_that_do_not_wrap_fail_the_reader_checks(built, served):
    """Mutation: every table cell on one line (`white-space: nowrap`, as the site's stylesheet once had for numbers)
    makes tables of the OOD page scroll in their boxes at 1400 px; the check names them."""
    require_browser()
    nowrap = ".bd-article table td, .bd-article table th { white-space: nowrap !important; }"
    with headless_chromium(TABLES_FIT_AT, 1000) as driver:
        page = served + "notebooks/03_ood_detection.html"
        assert not [p for p in reader_problems(driver, page, None) if "sideways in its box" in p]
        problems = reader_problems(driver, page, None, css=nowrap)
    assert any("scrolls" in p and "sideways in its box" in p for p in problems), problems


def test_a_figure_lost_from_an_executed_notebook_fails_the_reader_checks(built, tmp_path):
    """Mutation: the executed OOD notebook without one of its figures, rebuilt, shows one figure fewer than declared."""
    import dataclasses

    require_browser()
    page = next(p for p in built["pages"] if p.name == "03_ood_detection.ipynb")
    nb = nbformat.read(page.executed, as_version=4)
    cell = next(c for c in nb.cells if c.cell_type == "code" and any("image/png" in o.get("data", {}) for o in c.outputs))
    first = next(i for i, o in enumerate(cell.outputs) if "image/png" in o.get("data", {}))
    del cell.outputs[first]  # the first figure of the notebook's first figure cell
    nbformat.write(nb, tmp_path / page.name)
    src = tmp_path / "src"
    shutil.copytree(built["src"], src, ignore=shutil.ignore_patterns("*.ipynb", "docs", "README.md", "index.md",
                                                                     "claims.md"))
    (src / "index.md").write_text("# Mutated\n\n```{toctree}\nnotebooks/03_ood_detection\n```\n")
    text, files = project_site.page_notebook(dataclasses.replace(page, executed=tmp_path / page.name),
                                             project_site.active_profile())
    (src / f"{page.docname}.ipynb").write_text(text)
    index = project_site.build(src, tmp_path / "site", tmp_path / "doctrees", tmp_path / "warnings.txt")
    declared = len(project_site.declared_figures(ROOT / page.source, project_site.active_profile(), ROOT, page.executed))
    with headless_chromium() as driver:
        problems = reader_problems(driver, (index.parent / f"{page.docname}.html").as_uri(), declared)
    assert any(f"figures shown, its notebook declares {declared}" in p for p in problems), problems


def test_every_figure_offers_its_png_and_every_committed_table_its_csv(built):
    """A reader downloads what they see: beside each declared figure its PNG, beside each committed table its CSV."""
    profile = project_site.active_profile()
    committed = {path.with_suffix(".csv").name for path in project_site.table_files(profile).values()}
    for page in built["pages"]:
        html = (built["site"] / f"{page.docname}.html").read_text()
        offered = re.findall(r'href="(\.\./_downloads/[^"]+)"', html)
        for href in offered:
            assert (built["site"] / page.docname).parent.joinpath(unquote(href)).resolve().is_file(), (page.name, href)
        names = {unquote(href).rsplit("/", 1)[1] for href in offered}
        for figure in project_site.declared_figures(ROOT / page.source, profile, ROOT, page.executed):
            assert figure.file.name in names, f"{page.name}: no PNG offered beside {figure.file.name}"
        outputs = [out.get("data", {}).get("text/markdown", "") for cell in nbformat.read(page.executed, as_version=4).cells
                   if cell.cell_type == "code" for out in cell.outputs]
        shown = {path.with_suffix(".csv").name for text, path in project_site.table_files(profile).items()
                 if any(out.strip() == text for out in outputs)}
        assert shown <= names, f"{page.name}: no CSV beside {sorted(shown - names)}"
        assert shown <= committed


def test_every_page_names_its_commit_and_the_home_page_how_to_cite(built):
    """The commit in every page's foot; the arXiv link and both BibTeX entries on the home page; CITATION.cff, LICENSE."""
    import subprocess

    import yaml

    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    for path in _page_urls(built["site"], ""):
        assert f'<code class="site-commit">{head}' in (built["site"] / path).read_text(), f"{path}: no commit in its foot"
    home = (built["site"] / "index.html").read_text()
    text = re.sub(r"<[^>]+>", "", home)  # the BibTeX is highlighted: its words sit in spans
    assert project_site.ARXIV in home and "@article{" in text and "@software{" in text
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] and cff["license"] == "MIT"
    assert "Proximal Policy Optimization" in cff["preferred-citation"]["title"]
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")


def test_the_tables_pasted_into_the_docs_offer_their_csv(built):
    """docs/results.md and the README paste committed tables: each pasted one has its CSV beside it on the site."""
    tables = project_site.table_files(project_site.active_profile())
    for doc in ("docs/results", "README"):
        text = (ROOT / f"{doc}.md").read_text()
        pasted = {path.with_suffix(".csv").name for committed, path in tables.items()
                  if (block := project_site.table_block(committed)) and block + "\n" in text + "\n"}
        html = (built["site"] / f"{doc}.html").read_text()
        offered = {unquote(href).rsplit("/", 1)[1] for href in re.findall(r'href="([^"]*_downloads/[^"]+\.csv)"', html)}
        assert pasted and pasted <= offered, f"{doc}: no CSV beside {sorted(pasted - offered)}"


def test_a_declared_figure_is_expected_once_the_executed_copy_ran_its_cell(tmp_path):
    """A figure cell new in the source (not yet executed) is left out; one the executed copy ran must have its file."""
    import json

    (tmp_path / "results" / "p" / "figures").mkdir(parents=True)
    (tmp_path / "results" / "p" / "figures" / "old.png").write_bytes(b"png")
    cell = {"cell_type": "code", "metadata": {}, "outputs": [], "execution_count": None}
    old = {**cell, "source": "draw('old')", "metadata": {"figures": [{"files": "old.png", "caption": "c", "alt": "a"}]}}
    new = {**cell, "source": "draw('new')", "metadata": {"figures": [{"files": "new.png", "caption": "c", "alt": "a"}]}}
    source, executed = tmp_path / "source.ipynb", tmp_path / "executed.ipynb"
    source.write_text(json.dumps({"cells": [old, new]}))
    executed.write_text(json.dumps({"cells": [old]}))
    assert [f.file.name for f in project_site.declared_figures(source, "p", tmp_path, executed)] == ["old.png"]
    executed.write_text(json.dumps({"cells": [old, new]}))  # executed, and no file: the stage lost it
    with pytest.raises(ValueError, match="declares figures 'new.png'"):
        project_site.declared_figures(source, "p", tmp_path, executed)


def test_figures_that_reproduce_one_of_the_papers_name_its_number(built):
    """A declared label (`fig:reward_graphs`) reads as the number printed in the paper (Fig. 3), from
    data/paper_figures.csv; the training-curve page says so under its figure."""
    numbers = project_site.paper_figure_numbers()
    assert numbers["fig:reward_graphs"] == [3] and numbers["fig:scatter_mujoco"] == [4]
    assert project_site.paper_figure_names("fig:mujoco_id_ood_examples_, appendix H", numbers) == "Figs. 31, 32, appendix H"
    assert project_site.paper_figure_names("fig:no_such_label", numbers) == "fig:no_such_label"
    page = next(p for p in built["pages"] if "05_training" in p.source)
    html = (built["site"] / f"{page.docname}.html").read_text()
    assert re.search(r"Reproduces the paper(&#8217;|\u2019|')s Fig\. 3\.", html)  # Sphinx's smart quote


@pytest.mark.parametrize("verdict, kind", [
    ("holds", "holds"), ("does not hold, provisional (3 of 5 seeds)", "does not hold"),
    ("inconclusive (5 seeds)", "inconclusive"), ("inconclusive, provisional (4 of 5 seeds)", "inconclusive"),
    ("undecidable at 5 seeds (needs about 10)", "undecidable"),
    ("not testable (3 distinct OOD conditions; needs at least 5)", "not testable")])
def test_every_verdict_shape_of_the_claims_rules_has_its_colour(verdict, kind):
    """The matrix colours each verdict by its kind, whatever detail follows it (an env at its registered seeds reads
    'undecidable at n seeds (needs about m)': the site build once failed on it, issue 67)."""
    assert project_site.verdict_kind(verdict) == kind
    with pytest.raises(ValueError, match="is none of"):
        project_site.verdict_kind("holdsx")


def test_every_committed_verdict_has_its_colour():
    import csv

    with open(ROOT / "results" / "paper" / "tables" / "paper_claims.csv", newline="", encoding="utf-8") as f:
        verdicts = {row["verdict"] for row in csv.DictReader(f)}
    assert all(project_site.verdict_kind(v) in project_site.VERDICT_KINDS for v in verdicts)
