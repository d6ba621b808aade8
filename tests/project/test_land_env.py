"""scripts/land_env.py checks a whole env's runs before landing any: recipe moved, every run finished and trained as
params.yaml says (dry runs against the committed tree, with params.yaml edited in a temporary copy)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]


def dry_run(tmp_path: Path, params: dict, env_id: str) -> subprocess.CompletedProcess:
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return subprocess.run([sys.executable, str(REPO / "scripts/land_env.py"), env_id, str(REPO), "--dry-run"],
                          cwd=tmp_path, capture_output=True, text=True, env={"PYTHONPATH": str(REPO), "PATH": ""})


def committed_params() -> dict:
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params.pop("retraining", None)  # the committed runs are what `hyperparameters` trains
    params["run"]["seeds"] = [0, 1, 2]  # the committed seeds (issue 67's new ones land run by run, not with this)
    return params


def test_the_committed_runs_of_an_env_pass_with_its_members(tmp_path):
    run = dry_run(tmp_path, committed_params(), "Walker2d-v5")
    assert run.returncode == 0, run.stderr
    assert "20 runs of Walker2d-v5 finished and trained as params.yaml says" in run.stdout  # 15 + 5 members


def test_an_env_still_under_retraining_is_refused(tmp_path):
    params = committed_params()
    n_envs = params["hyperparameters"]["Ant-v5"]["n_envs"]
    params["retraining"] = {"Ant-v5": {**params["hyperparameters"]["Ant-v5"], "n_envs": 2 * n_envs}}
    run = dry_run(tmp_path, params, "Ant-v5")
    assert run.returncode != 0
    assert "move retraining.Ant-v5 into hyperparameters.Ant-v5 first" in run.stderr


def test_runs_of_another_recipe_are_named_and_nothing_lands(tmp_path):
    params = committed_params()
    gamma = params["hyperparameters"]["Ant-v5"]["algo"]["gamma"]
    params["hyperparameters"]["Ant-v5"]["algo"]["gamma"] = gamma + 0.01
    run = dry_run(tmp_path, params, "Ant-v5")
    assert run.returncode != 0 and "not landing anything" in run.stderr
    assert run.stderr.count(f"algo_kwargs.gamma: trained with {gamma!r}, params.yaml gives {gamma + 0.01!r}") == 15


def test_an_env_with_own_runs_is_refused(tmp_path):
    run = dry_run(tmp_path, committed_params(), "HalfCheetah-v5")
    assert run.returncode != 0 and "has `own` runs" in run.stderr
