"""The lease helper (scripts/gpu_runs.py), run here on the CPU: launch, stop, pack in parts, unpack, resume."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def load_gpu_runs():
    spec = importlib.util.spec_from_file_location("gpu_runs", REPO / "scripts" / "gpu_runs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_finished_and_a_stopped_run_come_back_and_the_stopped_one_resumes_here(tmp_path, monkeypatch):
    gpu_runs = load_gpu_runs()
    work, out, here, resume_root = (tmp_path / name for name in ("work", "out", "here", "resume"))
    gpu_runs.launch(work, [("CartPole-v1", "baseline", 0)], REPO, device="cpu", timesteps=512)
    gpu_runs.launch(work, [("CartPole-v1", "mc_dropout", 0)], REPO, device="cpu", timesteps=10**6, resume_every=128)
    state = gpu_runs.load_state(work)
    finished, stopped = state["runs"]
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (
            (work / gpu_runs.checkpoint_dir(finished) / "config.json").is_file()
            and gpu_runs.progress(work, stopped) > 0):
        time.sleep(0.1)
    gpu_runs.watch(work, until=0, stop_after=True)
    statuses = [r["status"] for r in gpu_runs.load_state(work)["runs"]]
    assert statuses == ["finished", "stopped"], statuses
    original = (gpu_runs.resume_point(work, stopped) / "state.pkl").read_bytes()
    reached = gpu_runs.progress(work, stopped)

    monkeypatch.setattr(gpu_runs, "PART_BYTES", 20_000)  # the resume point in several parts
    gpu_runs.pack(work, out / "call1", max_files=1)  # one call's worth: the checkpoint only
    gpu_runs.pack(work, out / "call2")
    assert [p.name for p in (out / "call1").iterdir()] == ["CartPole-v1_baseline_seed0.tar.gz"]
    parts = sorted(p.name for p in (out / "call2").iterdir())
    assert len(parts) > 1 and all(".resume.tar.part" in name for name in parts), parts

    here.mkdir()
    gpu_runs.unpack([out / "call1", out / "call2"], here, resume_root)
    config = json.loads((here / gpu_runs.checkpoint_dir(finished) / "config.json").read_text())
    assert config["trained_timesteps"] == 512 and config["env_processes"]
    placed = resume_root / here.resolve().relative_to("/") / gpu_runs.checkpoint_dir(stopped) / "state.pkl"
    assert placed.read_bytes() == original

    ckpt = here / gpu_runs.checkpoint_dir(stopped)
    done = subprocess.run([sys.executable, "-m", "paper_lib.train", "CartPole-v1", "mc_dropout", "0", str(ckpt),
                           "--timesteps", str(reached + 256), "--device", "cpu"], cwd=REPO, capture_output=True, text=True,
                          timeout=300, env={"PAPER_LIB_RESUME_ROOT": str(resume_root), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    assert f"resuming CartPole-v1 mc_dropout seed 0 from step {reached}" in done.stderr
    segments = json.loads((ckpt / "config.json").read_text())["segments"]
    assert [(s["from_step"], s["env_processes"]) for s in segments] == [(0, True), (reached, False)]
