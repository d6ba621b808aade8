"""scripts/training_progress.py: a session reports each long run's steps, status and hours left from its resume points."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from paper_lib.agents.factory import paper_hyperparameters
from paper_lib.agents.training import resume_dir_for, train_run

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "training_progress.py"
RUN = Path("paper/checkpoints/CartPole-v1/baseline/seed0")


def _progress(*trees: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, trees)], capture_output=True, text=True)


def _row(output: str, run: Path) -> list[str]:
    return next(line.split() for line in output.splitlines() if line.split()[:1] == [str(run)])


def test_finished_at_budget_and_in_progress_runs(tmp_path):
    recipe = {**paper_hyperparameters("CartPole-v1"), "n_envs": 1, "total_timesteps": 64}
    tiny = {"hyperparameters": recipe, "overrides": {"n_steps": 16, "batch_size": 16, "n_epochs": 1}}
    trees = {name: tmp_path / name for name in ("full", "half", "repo")}
    train_run("CartPole-v1", "baseline", 0, trees["full"] / "results" / RUN, agent_kwargs=tiny)
    train_run("CartPole-v1", "baseline", 0, trees["half"] / "results" / RUN, total_timesteps=32, agent_kwargs=tiny)
    committed = trees["repo"] / "results" / "resume_points"
    shutil.copytree(resume_dir_for(trees["full"] / "results" / RUN), committed / RUN)
    shutil.copytree(resume_dir_for(trees["half"] / "results" / RUN), committed / "paper/checkpoints/half/seed0")
    # the training tree's own committed copy (of the commit it was made from): behind its live run, not listed
    shutil.copytree(resume_dir_for(trees["half"] / "results" / RUN),
                    trees["full"] / "results" / "resume_points" / "paper/checkpoints/half/seed0")

    shown = _progress(trees["full"], trees["half"], trees["repo"])
    assert shown.returncode == 0, shown.stderr
    full, half, repo = (part for part in shown.stdout.split(str(tmp_path))[1:])
    assert _row(full, RUN)[1:5] == ["live", "finished", "64", "64"]
    assert "1 committed copies of this training tree's commit not listed" in full
    assert "paper/checkpoints/half/seed0" not in full
    # its own checkpoint says 32 steps were asked: finished at that budget, not in progress against the recipe's 64
    assert _row(half, RUN)[1:5] == ["live", "finished", "32", "32"]
    assert _row(repo, RUN)[1:6] == ["committed", "at", "budget", "64", "64"]  # lands from its resume point
    in_progress = _row(repo, Path("paper/checkpoints/half/seed0"))
    assert in_progress[1:6] == ["committed", "in", "progress", "32", "64"]
    steps_per_hour, hours_left = float(in_progress[-2]), float(in_progress[-1])
    assert steps_per_hour > 0 and hours_left == round((64 - 32) / steps_per_hour, 2), "hours left at its own speed"


def test_a_folder_without_results_is_refused(tmp_path):
    shown = _progress(tmp_path)
    assert shown.returncode == 2 and "has no results/ folder" in shown.stderr
