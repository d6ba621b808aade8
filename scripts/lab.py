"""Open the notebooks in JupyterLab on the project's .venv kernel (`make lab`).

    .venv/bin/python scripts/lab.py                      # port 8888 (or another free one), a fresh token
    .venv/bin/python scripts/lab.py --port 0 --token T   # any free port (tests/project/test_lab.py)

Why a launcher rather than plain `jupyter lab`: every notebook reads its inputs by paths relative to the repository
root (`params.yaml`, `results/<profile>/...`, as the DVC stages run them), while Jupyter starts a kernel in the
notebook's own folder. Here the server's root is the repository (the committed results are in its file browser),
JupyterLab opens at `notebooks/`, and every kernel starts in the repository root, so a notebook opened from
`notebooks/` or `results/<profile>/notebooks/` finds what its parameters name. The kernel is registered by this
script (kernelspec `python3`, the name every notebook asks for) under `build/jupyter/`, pointing at this
interpreter, the project's `.venv`. Autosave is off: the notebooks under `notebooks/` are inputs of DVC stages, so
a run here must not rewrite them behind the reader's back (File > Save As keeps a copy). JupyterLab's news and
update checks are off too: they would fetch from the network.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import socket
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
#: Everything this launcher writes: the kernelspec and JupyterLab's settings overrides (build/ is not committed).
JUPYTER_DIR = ROOT / "build" / "jupyter"
KERNEL_NAME = "python3"  # what every notebook's metadata asks for, so no notebook needs editing
KERNEL_DISPLAY_NAME = "Python 3 (paper_lib .venv)"
#: Where JupyterLab opens, relative to the repository root.
START_FOLDER = "notebooks"
#: JupyterLab settings the project sets for its readers (see the module docstring).
LAB_OVERRIDES: dict[str, dict[str, Any]] = {
    "@jupyterlab/docmanager-extension:plugin": {"autosave": False},
    "@jupyterlab/apputils-extension:notification": {"checkForUpdates": False, "fetchNews": "false"},
}


def register_kernel(jupyter_dir: Path = JUPYTER_DIR) -> Path:
    """Write the `python3` kernelspec for this interpreter under `jupyter_dir`; return its data dir (for JUPYTER_PATH).

    A kernelspec found on JUPYTER_PATH wins over the user's and the system's, so JupyterLab started by this
    script always runs the notebooks on the project's environment, whatever else the machine has registered.
    """
    from ipykernel.kernelspec import install

    prefix = jupyter_dir / "prefix"
    install(kernel_name=KERNEL_NAME, display_name=KERNEL_DISPLAY_NAME, prefix=str(prefix))
    spec_dir = prefix / "share" / "jupyter" / "kernels" / KERNEL_NAME
    spec = json.loads((spec_dir / "kernel.json").read_text())
    if Path(spec["argv"][0]).resolve() != Path(sys.executable).resolve():
        raise RuntimeError(f"{spec_dir / 'kernel.json'} runs {spec['argv'][0]}, not this interpreter {sys.executable}")
    return prefix / "share" / "jupyter"


def write_lab_settings(jupyter_dir: Path = JUPYTER_DIR) -> Path:
    """JupyterLab's app settings folder holding `overrides.json` (LAB_OVERRIDES); returned for `app_settings_dir`."""
    settings = jupyter_dir / "lab-settings"
    settings.mkdir(parents=True, exist_ok=True)
    (settings / "overrides.json").write_text(json.dumps(LAB_OVERRIDES, indent=2) + "\n")
    return settings


def free_port(wanted: int = 0) -> int:
    """`wanted` if nothing listens on it now, else a free TCP port the OS picks (so the printed address is right)."""
    for port in ((wanted, 0) if wanted else (0,)):
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return sock.getsockname()[1]
    raise OSError("no free local TCP port")


def lab_url(port: int, token: str, path: str = START_FOLDER) -> str:
    """The address that opens JupyterLab at `path` (a folder or a notebook, relative to the repository root)."""
    return f"http://127.0.0.1:{port}/lab/tree/{path}?token={token}"


def root_kernel_manager() -> type:
    """jupyter_server's kernel manager with one change: every kernel starts in the repository root.

    The notebooks' paths (`params.yaml`, `results/...`) are relative to the root, as the DVC stages run them; by
    default Jupyter would start the kernel in the notebook's folder, where none of them resolve.
    """
    from jupyter_server.services.kernels.kernelmanager import AsyncMappingKernelManager

    class RootKernelManager(AsyncMappingKernelManager):
        def cwd_for_path(self, path: str, **kwargs: Any) -> str:
            return str(ROOT)

    return RootKernelManager


def lab_config(port: int, token: str, open_browser: bool, app_settings_dir: Path) -> Any:
    """The server and JupyterLab settings of `make lab` (a traitlets Config)."""
    from traitlets.config import Config

    config = Config()
    config.ServerApp.root_dir = str(ROOT)
    config.ServerApp.ip = "127.0.0.1"
    config.ServerApp.port = port
    config.ServerApp.port_retries = 0  # the port was checked free just before: the printed address must be the one
    config.ServerApp.open_browser = open_browser
    config.ServerApp.allow_root = os.geteuid() == 0  # CI and containers run as root; Jupyter refuses it otherwise
    config.IdentityProvider.token = token
    config.ServerApp.kernel_manager_class = root_kernel_manager()
    config.KernelManager.transport = "ipc"  # local sockets, as paper_lib.pipeline.notebook_run runs kernels (not TCP)
    config.LabApp.default_url = f"/lab/tree/{START_FOLDER}"
    config.LabApp.app_settings_dir = str(app_settings_dir)
    config.LabApp.extension_manager = "readonly"  # no listing fetched from PyPI
    return config


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=8888, help="8888 by default (another free one if it is taken); "
                        "0: any free port")
    parser.add_argument("--token", default=None, help="the access token (default: a fresh random one)")
    parser.add_argument("--browser", action="store_true", help="also open a web browser on this machine")
    args = parser.parse_args(argv)
    port = free_port(args.port)
    token = args.token or secrets.token_hex(16)

    data_dir = register_kernel()
    os.environ["JUPYTER_PATH"] = os.pathsep.join([str(data_dir), *filter(None, [os.environ.get("JUPYTER_PATH")])])
    os.chdir(ROOT)
    print(f"JupyterLab on the .venv kernel ({sys.executable}), kernels start in {ROOT}.\n"
          f"Open {lab_url(port, token)}\nAutosave is off (notebooks/ are DVC stage inputs): keep changes with "
          "File > Save As. Ctrl+C stops the server.",
          flush=True)
    from jupyterlab.labapp import LabApp

    LabApp.initialize_server(argv=[], config=lab_config(port, token, args.browser, write_lab_settings())).start()


if __name__ == "__main__":
    main()
