"""scripts/train_queue.sh: lines run and are marked; in a session of its own it yields the CPU to other sessions."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "train_queue.sh"
AUTOGROUP = Path("/proc/self/autogroup")


def _autogroup_nice(pid: int | str) -> int | None:
    """The nice value of a process's autogroup (`/autogroup-N nice V`); None where the kernel shows none.

    A kernel with autogroup scheduling turned off (`noautogroup`, `kernel.sched_autogroup_enabled=0`)
    keeps the file but reads it empty, as CI's machine does.
    """
    fields = Path(f"/proc/{pid}/autogroup").read_text().split()
    return int(fields[-1]) if len(fields) == 3 and fields[1] == "nice" else None


def _autogroups_in_use() -> bool:
    """Whether this kernel schedules by autogroup and lets this process set its nice."""
    return AUTOGROUP.exists() and os.access(AUTOGROUP, os.W_OK) and _autogroup_nice("self") is not None


def _run(queue: Path, prefix: list[str]) -> tuple[int | None, str]:
    """Start the queue, read its autogroup's nice until its line has run, and wait for it to finish.

    Polled, not read once after a fixed sleep: on a loaded machine the script may set its nice late. The value
    returned is the last one read while the queue ran (its line sleeps 2 s, long after the script set it).
    """
    proc = subprocess.Popen([*prefix, "bash", str(SCRIPT), str(queue), "1"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.STDOUT)
    nice = None
    while proc.poll() is None:
        try:
            read = _autogroup_nice(proc.pid)
        except (FileNotFoundError, ProcessLookupError):  # it ended between poll() and the read
            break
        nice = nice if read is None else read  # an exiting process may read empty
        time.sleep(0.05)
    assert proc.wait(timeout=30) == 0
    return nice, queue.read_text()


@pytest.mark.skipif(not _autogroups_in_use(),
                    reason="no autogroup scheduling here (or it is off), or its setting is not writable")
def test_a_queue_in_its_own_session_lowers_its_autogroup_and_never_the_callers(tmp_path: Path):
    before = _autogroup_nice("self")
    queue = tmp_path / "q"
    queue.write_text("sleep 2\n")
    nice, text = _run(queue, ["setsid"])
    assert nice == 10 and text == "#done sleep 2\n"

    queue.write_text("sleep 2\n")
    nice, text = _run(queue, [])  # in the caller's session: the caller's autogroup stays as it was
    assert nice == before and _autogroup_nice("self") == before and text == "#done sleep 2\n"
