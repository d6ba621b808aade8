"""Execute a pipeline notebook with papermill and save it without run metadata (what every DVC stage calls).

    python -m paper_lib.pipeline.notebook_run notebooks/02_rewards.ipynb results/cpu/notebooks/02_rewards.ipynb
    python -m paper_lib.pipeline.notebook_run notebooks/00_quickstart.ipynb out.ipynb -p checkpoint path/to/run

Why not the papermill CLI: an executed notebook records start/end times, durations and random
cell ids, so every regeneration would change the committed notebooks (and their hashes in
dvc.lock) although no result changed. nbstripout removes that metadata here, before DVC hashes
the file, and keeps outputs and execution counts. This is also the one place that keeps the
notebook runner quiet: the kernel talks to papermill over local IPC sockets (not TCP, which
ipykernel warns is unencrypted), papermill's progress bar is off, and the kernel drops its
"KeyboardInterrupt caught in kernel" line at shutdown (see QUIET_KERNEL). The executed notebook is
written atomically and only when every cell ran, so a failing stage leaves no half-made copy.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

#: nbformat and papermill import jsonschema, which compiles rfc3987-syntax's 38 Lark grammars at import (about 2.5 s of
#: every notebook stage here) to check the `iri` string formats, which no notebook schema uses: the runner goes
#: without them (jsonschema skips a format whose checker cannot be imported). The kernel is a process of its own.
sys.modules.setdefault("rfc3987_syntax", None)  # type: ignore[arg-type]

import nbformat  # noqa: E402
import yaml  # noqa: E402

from paper_lib.common.io import check_file_destination, write_text_atomic  # noqa: E402

#: jupyter_client interrupts a kernel before asking it to shut down; when the interrupt lands while the kernel still
#: answers a message, ipykernel logs "KeyboardInterrupt caught in kernel". The notebook has finished by then: the
#: line says nothing about it, so the kernel drops that one message (installed at kernel start, before any cell).
#: Likewise tqdm's "IProgress not found" warning (tqdm.auto without ipywidgets, imported by Optuna): it names the
#: absolute path of the virtual environment, so the executed notebook would differ between two clones.
QUIET_KERNEL = ("__import__('logging').getLogger('IPKernelApp').addFilter("
                "lambda record: 'KeyboardInterrupt caught in kernel' not in record.getMessage()); "
                "__import__('warnings').filterwarnings('ignore', message='IProgress not found')")

#: Run metadata that differs between two executions of the same notebook on the same inputs.
RUN_METADATA_KEYS = (
    "metadata.papermill", "cell.metadata.papermill", "cell.metadata.execution", "cell.metadata.ExecuteTime",
    "metadata.widgets", "metadata.signature",
)


def strip_run_metadata(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Outputs and execution counts kept; timestamps, durations, papermill records and random cell ids dropped."""
    from nbstripout import strip_output

    return strip_output(nb, keep_output=True, keep_count=True, keep_id=False, extra_keys=list(RUN_METADATA_KEYS))


def _default_kind(default: str) -> type | None:
    """The kind of value a parameter's default literal is (int, float, bool, str, list), None where any goes."""
    import ast

    try:
        value = ast.literal_eval(default)
    except (ValueError, SyntaxError):
        return None  # an expression: nothing to compare with
    return None if value is None else type(value)


def _fits(value: Any, kind: type) -> bool:
    """Whether `value` is of `kind` (an int where a float is the default is fine; a bool is no number here)."""
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, kind)


def check_parameters(source: Path, parameters: dict[str, Any]) -> None:
    """papermill only warns about a parameter the notebook lacks, and the run goes on with the default: refuse it.

    A value of another kind than the default's (`-p n_id_states abc` where the default is 2000) is refused here too,
    by its name: inside the notebook it would fail later, in whatever cell first used it, with a misleading cause.
    """
    if not parameters:
        return
    import papermill as pm

    declared = pm.inspect_notebook(str(source))
    unknown = sorted(set(parameters) - set(declared))
    if unknown:
        have = f"its parameters are {', '.join(declared)}" if declared else "it has no cell tagged `parameters`"
        given = ", ".join(f"-p {name}" for name in unknown)
        raise ValueError(f"unknown parameter(s) of {source}, got {given}; {have}: fix the name (nothing was executed)")
    for name, value in parameters.items():
        kind = _default_kind(declared[name]["default"])
        if kind is not None and not _fits(value, kind):
            a = "an" if kind.__name__[0] in "aeiou" else "a"
            raise ValueError(f"parameter {name} of {source} takes {a} {kind.__name__} (default "
                             f"{declared[name]['default']}), got {value!r}; give {a} {kind.__name__} (nothing was executed)")


def run_notebook(source: str | os.PathLike[str], target: str | os.PathLike[str],
                 parameters: dict[str, Any] | None = None, kernel_name: str = "python3") -> Path:
    """Execute `source` with `parameters` (papermill), strip run metadata and write `target` atomically."""
    import papermill as pm
    from traitlets.config import Config

    source, target = Path(source), Path(target)
    if not source.is_file():
        raise ValueError(f"notebook {source} not found; run from the repository root (notebooks/ is there)")
    if target.suffix != ".ipynb":
        raise ValueError(f"the executed notebook must be written to a .ipynb file, got {target}")
    check_file_destination(target, "executed notebook")
    check_parameters(source, parameters or {})
    nb = pm.execute_notebook(str(source), None, parameters=parameters or {}, kernel_name=kernel_name,
                             progress_bar=False, log_output=False,
                             config=Config({"KernelManager": {"transport": "ipc"}}),
                             extra_arguments=[f"--IPKernelApp.exec_lines={QUIET_KERNEL}"])
    write_text_atomic(target, nbformat.writes(strip_run_metadata(nb)) + "\n")
    return target


def _parse_value(text: str) -> Any:
    """`-p name value` values are YAML, as papermill's CLI reads them: 3 -> int, true -> bool, a/b -> str."""
    value = yaml.safe_load(text)
    return text if value is None and text not in ("null", "~", "") else value


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="the notebook to execute (notebooks/...)")
    parser.add_argument("target", help="where the executed notebook goes (results/<profile>/notebooks/...)")
    parser.add_argument("-p", "--parameter", nargs=2, action="append", default=[], metavar=("NAME", "VALUE"),
                        help="a notebook parameter (YAML value), as papermill's -p")
    args = parser.parse_args(argv)
    try:
        run_notebook(args.source, args.target, {name: _parse_value(value) for name, value in args.parameter})
    except ValueError as err:
        parser.exit(2, f"error: {err}\n")
    except Exception as err:  # a failing cell: papermill's message names the cell and holds its traceback
        if type(err).__name__ != "PapermillExecutionError":
            raise
        print(err, file=sys.stderr)
        parser.exit(1, f"error: {args.source} failed in a cell (traceback above); {args.target} was not written\n")


if __name__ == "__main__":
    main()
