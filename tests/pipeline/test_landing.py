"""A checkpoint enters the tables only if it was trained as params.yaml trains it (paper_lib.pipeline.landing)."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.landing import check_landing, mismatches

REPO = Path(__file__).resolve().parents[2]
RUN = ("Walker2d-v5", "masksembles", 1)


def test_every_committed_checkpoint_was_trained_as_params_says():
    """No table reads a run of another recipe, budget or method: each finished run of the active profile
    matches the settings its train stage would use today (runs not trained yet are skipped)."""
    cfg = dataclasses.replace(load_run_config(REPO / "params.yaml"), root=REPO)
    finished = [run for run in cfg.runs() if (cfg.checkpoint_dir(*run) / "model.zip").is_file()]
    assert len(finished) >= 60  # the MuJoCo matrix at least: the test must not pass on an empty tree
    wrong = {run: problems for run in finished if (problems := mismatches(cfg, *run))}
    assert not wrong


@pytest.fixture
def landing_tree(tmp_path):
    """A copy of one committed run's config beside a stand-in model.zip, in a results tree under tmp_path."""
    cfg = load_run_config(REPO / "params.yaml")
    committed = REPO / cfg.checkpoint_dir(*RUN)
    moved = dataclasses.replace(cfg, root=tmp_path)
    folder = moved.checkpoint_dir(*RUN)
    folder.mkdir(parents=True)
    shutil.copy(committed / "config.json", folder / "config.json")
    (folder / "model.zip").write_bytes(b"only its presence is read")
    return moved, folder


def edit_config(folder: Path, **changes) -> None:
    config = json.loads((folder / "config.json").read_text())
    for key, value in changes.items():
        if key.startswith("algo_kwargs."):
            config["algo_kwargs"][key.split(".", 1)[1]] = value
        else:
            config[key] = value
    (folder / "config.json").write_text(json.dumps(config))


def test_a_run_of_another_recipe_is_refused_naming_each_setting(landing_tree):
    cfg, folder = landing_tree
    check_landing(cfg, *RUN)  # the committed run as it is lands
    config = json.loads((folder / "config.json").read_text())
    n_envs, gamma = config["n_envs"], config["algo_kwargs"]["gamma"]
    edit_config(folder, n_envs=2 * n_envs, **{"algo_kwargs.gamma": gamma - 0.01})
    with pytest.raises(ValueError) as err:
        check_landing(cfg, *RUN)
    message = str(err.value)
    assert f"n_envs: trained with {2 * n_envs}, params.yaml gives {n_envs}" in message
    assert f"algo_kwargs.gamma: trained with {gamma - 0.01!r}, params.yaml gives {gamma!r}" in message
    assert "update params.yaml first" in message and "retrain" in message


def test_a_run_of_another_seed_or_a_shorter_budget_is_refused(landing_tree):
    cfg, folder = landing_tree
    edit_config(folder, seed=0, trained_timesteps=1000)
    budget = json.loads((folder / "config.json").read_text())["total_timesteps"]
    assert mismatches(cfg, *RUN) == ["seed: trained with 0, params.yaml gives 1",
                                     f"trained_timesteps: 1000, fewer than the budget {budget}"]


def test_the_command_line_names_unfinished_runs_and_fails(tmp_path):
    """`python -m paper_lib.pipeline.landing` (what scripts/land_run.sh runs first) exits non-zero, naming the run."""
    shutil.copy(REPO / "params.yaml", tmp_path / "params.yaml")
    run = subprocess.run([sys.executable, "-m", "paper_lib.pipeline.landing", *map(str, RUN)], cwd=tmp_path,
                         capture_output=True, text=True, env={"PYTHONPATH": str(REPO), "PATH": ""})
    assert run.returncode != 0
    assert "results/paper/checkpoints/Walker2d-v5/masksembles/seed1/model.zip is missing" in run.stderr


def test_an_independent_member_is_held_to_every_training_setting_of_the_rule(tmp_path):
    """Not only the algorithm settings: a member stepping another number of envs is not a member of the rule."""
    from paper_lib.experiments import ensembles as ens

    cfg = ens.load_ensembles_config(REPO / "params.yaml")
    env_id = cfg.envs[0]
    committed = REPO / cfg.member_dir(env_id, 0)
    cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, root=tmp_path))
    folder = cfg.member_dir(env_id, 0)
    folder.mkdir(parents=True)
    shutil.copy(committed / "config.json", folder / "config.json")
    (folder / "model.zip").write_bytes(b"only its presence is read")
    assert ens.member_problem(cfg, env_id, 0) is None
    n_envs = json.loads((folder / "config.json").read_text())["n_envs"]
    edit_config(folder, n_envs=n_envs + 1)
    assert ens.member_problem(cfg, env_id, 0) == (f"not trained as the rule trains it (n_envs: trained with "
                                                  f"{n_envs + 1}, params.yaml gives {n_envs}); retrain it")
