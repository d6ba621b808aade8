"""scripts/pedm_queue.sh: PEDM's protocol played run after run, its output copied back only while no rebuild reads it."""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
RUNS = [("Swimmer-v5", "baseline", 0), ("Swimmer-v5", "masksembles", 0)]
#: Stands in for `python -m paper_lib.pipeline.pedm_stage ENV METHOD SEED` in the worktree: writes the run's folder.
FAKE_STAGE = """#!/usr/bin/env bash
env_id=$3 method=$4 seed=$5
out="results/paper/pedm/$env_id/$method/seed$seed"
mkdir -p "$out" && echo "$method" > "$out/table2_metrics.csv" && echo '{"settings": {}}' > "$out/provenance.json"
echo "$env_id $method $seed" >> played.log
"""


def _repository(root: Path) -> None:
    """A repository with the script, two MuJoCo runs in runs.yaml and the real environment's python."""
    (root / "scripts").mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "pedm_queue.sh", root / "scripts")
    (root / ".venv").symlink_to(REPO / ".venv")
    runs = {f"{e}-{m}-{s}": {"env": e, "method": m, "seed": s} for e, m, s in RUNS}
    (root / "runs.yaml").write_text(yaml.safe_dump({"sequence_runs": runs}))
    (root / "params.yaml").write_text(yaml.safe_dump({"pedm": {"epochs": 60}}))


def _worktree(root: Path) -> None:
    """A worktree (its .git present, so the script makes none) whose python is FAKE_STAGE."""
    (root / ".venv" / "bin").mkdir(parents=True)
    (root / ".git").write_text("gitdir: elsewhere\n")
    python = root / ".venv" / "bin" / "python"
    python.write_text(FAKE_STAGE)
    python.chmod(0o755)


def _wait_for(condition, what: str, timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.2)


def test_the_queue_keeps_playing_during_a_hold_and_copies_once_it_ends(tmp_path):
    repo, tree = tmp_path / "repo", tmp_path / "tree"
    _repository(repo)
    _worktree(tree)
    hold = tmp_path / "tree.hold"
    hold.touch()
    queue = subprocess.Popen(["bash", str(repo / "scripts" / "pedm_queue.sh"), str(tree)], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    try:
        played = tree / "played.log"
        _wait_for(lambda: played.is_file() and len(played.read_text().splitlines()) == len(RUNS), "both runs")
        assert queue.poll() is None  # it waits to copy
        assert not (repo / "results").exists()  # nothing reaches the repository while the hold stands
        hold.unlink()
        output, _ = queue.communicate(timeout=60)
    finally:
        queue.kill()
    assert queue.returncode == 0, output
    for env_id, method, seed in RUNS:
        copied = repo / "results" / "paper" / "pedm" / env_id / method / f"seed{seed}" / "table2_metrics.csv"
        assert copied.read_text() == f"{method}\n"
    assert output.count("copied ") == len(RUNS)
