"""The results website (`make site`, scripts/build_site.py), built from the committed files and read in a real browser.

The site is built once per module into tmp folders (the same code `make site` runs), served on a free local port,
and walked in headless chromium: every page loads, every image loads, every internal link (and its #anchor)
resolves, nothing is fetched from outside the site, and Sphinx's search finds a method name.
"""

from __future__ import annotations

import functools
import http.server
import re
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


def test_the_site_builds_offline_within_budget(built):
    profile = project_site.active_profile()
    executed = sorted(p.name for p in (ROOT / "results" / profile / "notebooks").glob("*.ipynb"))
    assert [page.name for page in built["pages"]] == executed
    assert built["index"].is_file()
    assert built["seconds"] < BUILD_BUDGET_S, f"the site took {built['seconds']:.0f} s to build"
    assert "WARNING" not in built["warnings"], built["warnings"]
    print(f"site built in {built['seconds']:.0f} s")


def test_home_page_opens_with_the_headline_then_every_table_and_figure_page(built):
    home = (built["src"] / "index.md").read_text()
    headline = home.index(project_site.HEADLINE_HEADING)
    readme_table = (ROOT / "README.md").read_text().split("<!-- headline:start -->")[1].split("<!-- headline:end -->")[0]
    assert readme_table.strip() in home
    assert headline < home.index("## The paper's tables and figures")
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
        stage = f'<strong><code class="docutils literal notranslate"><span class="pre">{page.stage}</span></code></strong>'
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
