"""`make lab` (scripts/lab.py): JupyterLab on the project's kernel, tried in a real headless browser.

The server is started as `make lab` starts it (on a free port, with a token, its user settings and workspaces in a
tmp folder); chromium opens notebooks/00_quickstart.ipynb, runs every cell from JupyterLab's Run menu, and the test
checks that every cell ran without an error, that a figure appears, and that the notebook on disk is untouched.
"""

from __future__ import annotations

import json
import os
import secrets
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from _browser import headless_chromium, keep_screenshot, require_browser, wait_for

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

import lab  # noqa: E402

QUICKSTART = "notebooks/00_quickstart.ipynb"
#: Seconds for the quickstart's cells (about 25 s on a busy 2-core machine) and for JupyterLab to start.
RUN_TIMEOUT, START_TIMEOUT = 600, 180


class Lab:
    """A running `scripts/lab.py` server: its port, token and process."""

    def __init__(self, process: subprocess.Popen, port: int, token: str, log: Path) -> None:
        self.process, self.port, self.token, self.log = process, port, token, log

    def api(self, path: str, method: str = "GET") -> object:
        request = urllib.request.Request(f"http://127.0.0.1:{self.port}{path}", method=method,
                                         headers={"Authorization": f"token {self.token}"})
        with urllib.request.urlopen(request, timeout=30) as response:
            body = response.read()
        return json.loads(body) if body else None

    def kernel_idle(self, path: str) -> bool:
        """Whether the server runs a kernel for the notebook at `path` and that kernel is idle."""
        return any(session["path"] == path and session["kernel"]["execution_state"] == "idle"
                   for session in self.api("/api/sessions"))

    def up(self) -> bool:
        if self.process.poll() is not None:
            raise AssertionError(f"scripts/lab.py exited with {self.process.returncode}:\n{self.log.read_text()}")
        try:
            return self.api("/api/status") is not None
        except (urllib.error.URLError, ConnectionError, OSError):
            return False


@pytest.fixture(scope="module")
def running_lab(tmp_path_factory) -> Iterator[Lab]:
    """scripts/lab.py on a free port; Jupyter's config, runtime, settings and workspaces kept in a tmp folder."""
    home = tmp_path_factory.mktemp("lab")
    env = {**os.environ, "JUPYTER_CONFIG_DIR": str(home / "config"), "JUPYTER_RUNTIME_DIR": str(home / "runtime"),
           "JUPYTERLAB_SETTINGS_DIR": str(home / "settings"), "JUPYTERLAB_WORKSPACES_DIR": str(home / "workspaces")}
    port, token = lab.free_port(), secrets.token_hex(16)
    log = home / "lab.log"
    with log.open("w") as out:
        process = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "lab.py"), "--port", str(port),
                                    "--token", token], cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT)
    server = Lab(process, port, token, log)
    try:
        wait_for(server.up, START_TIMEOUT, "JupyterLab to answer")
        yield server
    finally:
        try:
            for kernel in server.api("/api/kernels") if process.poll() is None else []:
                server.api(f"/api/kernels/{kernel['id']}", method="DELETE")
        finally:
            process.terminate()
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def test_the_server_offers_the_venv_kernel_and_opens_at_the_notebooks(running_lab):
    specs = running_lab.api("/api/kernelspecs")
    spec = specs["kernelspecs"][lab.KERNEL_NAME]["spec"]
    assert Path(spec["argv"][0]).resolve() == Path(sys.executable).resolve()
    assert spec["display_name"] == lab.KERNEL_DISPLAY_NAME
    request = urllib.request.Request(f"http://127.0.0.1:{running_lab.port}/?token={running_lab.token}")
    opener = urllib.request.build_opener(_NoRedirect)
    with pytest.raises(urllib.error.HTTPError) as redirect:
        opener.open(request, timeout=30)
    assert redirect.value.headers["Location"].split("?")[0].endswith(f"/lab/tree/{lab.START_FOLDER}")
    settings = running_lab.api("/lab/api/settings/@jupyterlab/docmanager-extension:plugin")
    assert settings["schema"]["properties"]["autosave"]["default"] is False


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args, **kwargs):
        return None


@pytest.mark.filterwarnings("ignore:Cell is missing an id field")  # the committed notebooks carry none (nbstripout)
def test_notebook_parameters_point_at_files_of_the_active_profile():
    """What a notebook's parameters name by default exists from the kernel's folder (the repository root) and
    belongs to the active profile, so a notebook opened in JupyterLab runs on the committed results as it is."""
    import papermill as pm

    from paper_lib.pipeline.config import load_run_config

    profile = load_run_config(ROOT / "params.yaml").profile
    wrong = []
    for notebook in sorted((ROOT / "notebooks").glob("*.ipynb")):
        for name, parameter in pm.inspect_notebook(str(notebook)).items():
            value = parameter["default"].strip("\"'")
            if "/" not in value and not value.endswith((".yaml", ".npz", ".db")):
                continue  # not a path
            if not (ROOT / value).exists():
                wrong.append(f"{notebook.name}: {name} = {value} does not exist")
            if value.startswith("results/") and not value.startswith(f"results/{profile}/"):
                wrong.append(f"{notebook.name}: {name} = {value} is not the active profile's ({profile})")
    assert not wrong, "\n".join(wrong)


def test_quickstart_runs_in_jupyterlab_in_a_real_browser(running_lab, tmp_path):
    """Open the quickstart, Run > Run All Cells, as a reader would: every cell runs, none errs, a figure shows."""
    require_browser()
    before = (ROOT / QUICKSTART).read_bytes()
    panel = ".jp-NotebookPanel:not(.lm-mod-hidden)"
    with headless_chromium() as driver:
        try:
            driver.get(lab.lab_url(running_lab.port, running_lab.token, QUICKSTART))
            wait_for(lambda: driver.execute_script(f"return document.querySelector('{panel} .jp-Cell') !== null"),
                     START_TIMEOUT, "the quickstart to open")
            status = f"return document.querySelector('{panel} .jp-Notebook-ExecutionIndicator')?.getAttribute('data-status')"
            wait_for(lambda: running_lab.kernel_idle(QUICKSTART) and driver.execute_script(status) == "idle",
                     START_TIMEOUT, "the kernel to start")  # the page says idle before a kernel is there too
            kernel = driver.execute_script(f"return document.querySelector('{panel} .jp-Toolbar-kernelName')?.textContent.trim()")
            menu = driver.find_element("xpath", "//div[contains(@class,'lm-MenuBar-itemLabel') and text()='Run']")
            menu.click()
            wait_for(lambda: driver.find_elements("css selector", "li.lm-Menu-item[data-command='runmenu:run-all']"),
                     30, "the Run menu")[0].click()
            prompts = f"return Array.from(document.querySelectorAll('{panel} .jp-CodeCell .jp-InputPrompt')).map(e => e.textContent.trim())"
            started = time.monotonic()
            wait_for(lambda: any(p not in ("[ ]:", "") for p in driver.execute_script(prompts)), 60, "the run to start")
            wait_for(lambda: driver.execute_script(status) == "idle" and not any("*" in p for p in driver.execute_script(prompts)),
                     RUN_TIMEOUT, "every cell of the quickstart to run")
            seconds = time.monotonic() - started
            ran = driver.execute_script(prompts)
            outputs = driver.execute_script(
                f"return Array.from(document.querySelectorAll('{panel} .jp-OutputArea-output')).map(e => e.textContent)")
            images = driver.execute_script(
                f"return Array.from(document.querySelectorAll('{panel} .jp-OutputArea-output img')).map(i => i.naturalWidth)")
            if images:
                driver.execute_script(f"document.querySelector('{panel} .jp-OutputArea-output img').scrollIntoView()")
            keep_screenshot(driver, tmp_path, "lab_quickstart.png")
        except Exception:
            keep_screenshot(driver, tmp_path, "lab_failure.png")  # what the reader would have seen
            raise
    errors = [text[:2000] for text in outputs if "Traceback (most recent call last)" in text]
    assert not errors, "a cell failed in JupyterLab:\n" + "\n".join(errors)
    assert ran and all(p.startswith("[") and p[1:-2].isdigit() for p in ran), f"cells left unrun (after an error?): {ran}"
    assert images and all(width > 0 for width in images), f"no figure appeared: image widths {images}"
    assert kernel == lab.KERNEL_DISPLAY_NAME, kernel
    assert (ROOT / QUICKSTART).read_bytes() == before, "running in JupyterLab rewrote the notebook (autosave is off)"
    print(f"quickstart ran in JupyterLab in {seconds:.0f} s")
