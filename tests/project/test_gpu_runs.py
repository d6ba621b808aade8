"""The lease helper (scripts/gpu_runs.py), run here on the CPU: launch, stop, pack in parts, unpack, resume."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def load_gpu_runs():
    spec = importlib.util.spec_from_file_location("gpu_runs", REPO / "scripts" / "gpu_runs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_finished_and_a_stopped_run_come_back_and_the_stopped_one_resumes_here(tmp_path, monkeypatch):
    gpu_runs = load_gpu_runs()
    work, out, here, resume_root = (tmp_path / name for name in ("work", "out", "here", "resume"))
    queue = tmp_path / "queue.txt"  # as `python -m paper_lib.experiments.ensembles queue` prints it: own folder, own arguments
    queue.write_text("#done env X=1 python -m paper_lib.agents.training CartPole-v1 mc_dropout 1 results/x/seed1\n"
                     "env PAPER_LIB_RESUME_ROOT=/r .venv/bin/python -m paper_lib.agents.training CartPole-v1 baseline 0 "
                     "results/paper/independent/checkpoints/CartPole-v1/baseline/seed0 --timesteps 512 --hp algo.n_epochs=2\n")
    gpu_runs.launch(work, gpu_runs.read_queue(queue), REPO, device="cpu")
    gpu_runs.launch(work, [gpu_runs.main_matrix_run("CartPole-v1", "mc_dropout", 0)], REPO, device="cpu",
                    timesteps=10**6, resume_every=128)
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

    monkeypatch.setattr(gpu_runs, "PART_BYTES", 20_000)  # every tar in several parts, two parts per call
    calls = []
    while not calls or any(not r.get("packed") for r in gpu_runs.load_state(work)["runs"]):
        calls.append(out / f"call{len(calls)}")
        gpu_runs.pack(work, calls[-1], max_files=2)
        assert len(calls) < 100
    sent = [sorted(p.name for p in call.iterdir()) for call in calls]
    assert all(len(names) <= 2 for names in sent), sent
    assert sent[0][0] == "paper_independent_CartPole-v1_baseline_seed0.checkpoint.tar.part01of" + sent[0][0][-2:]
    resume_calls = [i for i, names in enumerate(sent) if any(".resume.tar." in n for n in names)]
    assert len(resume_calls) > 1, sent  # one resume point spread over calls, as an Atari Ensemble's (~80 MB)

    here.mkdir()
    with pytest.raises(SystemExit, match="lacks parts"):  # a call's folder left out: refused, nothing written
        gpu_runs.unpack(calls[:-1], here, resume_root)
    assert not resume_root.exists() and not any(here.iterdir())
    gpu_runs.unpack(calls, here, resume_root)
    with pytest.raises(SystemExit, match="already exists"):
        gpu_runs.unpack(calls, here, resume_root)
    config = json.loads((here / "results/paper/independent/checkpoints/CartPole-v1/baseline/seed0/config.json").read_text())
    assert config["trained_timesteps"] == 512 and config["env_processes"]
    assert config["algo_kwargs"]["n_epochs"] == 2, config["algo_kwargs"]
    placed = (resume_root / here.resolve().relative_to("/") / "results/paper/checkpoints/CartPole-v1/mc_dropout/seed0"
              / "state.pkl")
    assert placed.read_bytes() == original

    ckpt = here / gpu_runs.checkpoint_dir(stopped)
    done = subprocess.run([sys.executable, "-m", "paper_lib.agents.training", "CartPole-v1", "mc_dropout", "0", str(ckpt),
                           "--timesteps", str(reached + 256), "--device", "cpu"], cwd=REPO, capture_output=True, text=True,
                          timeout=300, env={"PAPER_LIB_RESUME_ROOT": str(resume_root), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    assert f"resuming CartPole-v1 mc_dropout seed 0 from step {reached}" in done.stderr
    segments = json.loads((ckpt / "config.json").read_text())["segments"]
    assert [(s["from_step"], s["env_processes"]) for s in segments] == [(0, True), (reached, False)]


def test_bad_inputs_are_one_error_each_and_write_nothing(tmp_path):
    def gpu_runs(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, str(REPO / "scripts" / "gpu_runs.py"), *args],
                              capture_output=True, text=True, timeout=60)

    queue = tmp_path / "queue.txt"
    queue.write_text("python -m paper_lib.agents.training CartPole-v1 baseline zero results/x\n")
    done = gpu_runs("launch", str(tmp_path / "work"), "--queue", str(queue))
    assert done.returncode == 2 and "paper_lib.pipeline.status queue" in done.stderr, done.stderr
    queue.write_text("python -m paper_lib.agents.training CartPole-v1 baseline 0 /tmp/elsewhere\n")
    done = gpu_runs("launch", str(tmp_path / "work"), "--queue", str(queue))
    assert done.returncode == 2 and "relative to the repository" in done.stderr, done.stderr
    done = gpu_runs("launch", str(tmp_path / "work"), "CartPole-v1", "baseline", "zero")
    assert done.returncode == 2 and "integer seed" in done.stderr, done.stderr
    assert not (tmp_path / "work").exists()
    done = gpu_runs("pack", str(tmp_path), "--out", str(tmp_path / "out"))
    assert done.returncode == 2 and "no launched runs" in done.stderr, done.stderr
    done = gpu_runs("unpack", str(tmp_path / "absent"), "--resume-root", str(tmp_path / "resume"))
    assert done.returncode == 2 and "not a folder" in done.stderr, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["queue.txt"]
