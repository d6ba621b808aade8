"""The lease helper's triage: runs that cannot all finish by the deadline give their cores to the first-listed."""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def load_gpu_runs():
    spec = importlib.util.spec_from_file_location("gpu_runs", REPO / "scripts" / "gpu_runs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def sleeper() -> int:
    return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True).pid


def test_the_last_listed_run_is_killed_when_a_run_would_miss_the_deadline():
    gpu_runs = load_gpu_runs()
    launched, now = 1000.0, 1400.0
    # 2000 steps/s over the last minute: 620k steps left take 310 s, ending 700 s after launch
    runs = [{"env": "A", "method": m, "seed": 0, "status": "running", "pid": sleeper(),
             "history": [[now - 70, 260_000], [now - 10, 380_000]]} for m in ("first", "last")]
    state = {"launched": launched, "runs": runs}
    try:
        gpu_runs.triage(state, now, deadline=800, budget=1_000_000)
        assert [r["status"] for r in runs] == ["running", "running"], "both finish by 800 s"
        gpu_runs.triage(state, now, deadline=650, budget=1_000_000)
        assert [r["status"] for r in runs] == ["running", "killed"]
        os.waitpid(runs[1]["pid"], 0)
        assert not gpu_runs.alive(runs[1]["pid"]) and gpu_runs.alive(runs[0]["pid"])
        gpu_runs.triage(state, now + 30, deadline=650, budget=1_000_000)
        assert runs[0]["status"] == "running", "no second kill before the rates of the survivors are measured again"
    finally:
        for run in runs:
            if run["status"] == "running":
                os.killpg(run["pid"], signal.SIGKILL)
