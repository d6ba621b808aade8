"""params.yaml: profiles, validation and clear errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.agents.factory import paper_hyperparameters
from paper_lib.agents.training import train_run
from paper_lib.pipeline.config import load_run_config, use_profile

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def params(tmp_path) -> Path:
    path = tmp_path / "params.yaml"
    shutil.copy(REPO / "params.yaml", path)
    return path


def test_committed_profile_is_valid_and_profiles_switch(params):
    assert load_run_config(params).profile in ("cpu", "tiny", "paper")
    use_profile("tiny", params)
    cfg = load_run_config(params)
    assert cfg.profile == "tiny" and cfg.results.name == "tiny"
    use_profile("paper", params)
    paper = load_run_config(params)
    # issue 67: the paper's 3 seeds on Atari, 5 on MuJoCo, as the pre-registration plans them
    assert paper.seeds_for("SeaquestNoFrameskip-v4") == [0, 1, 2] and paper.seeds_for("Ant-v5") == [0, 1, 2, 3, 4]
    assert len(paper.runs()) == 5 * (4 * 5 + 4 * 3) and paper.all_seeds == [0, 1, 2, 3, 4]
    from paper_lib.pipeline.config import read_params
    from paper_lib.reporting.preregistration import Preregistration

    prereg = Preregistration.from_params(read_params(params))
    assert all(paper.seeds_for(env) == prereg.planned(env) for env in paper.envs)
    # every env at its own (the paper's) budget, Ant's 1e7 included since its runs landed (issue 38)
    assert paper.budget("Ant-v5") is None and paper.budget("HalfCheetah-v5") is None
    assert "the paper's training steps per run" in paper.budget_caption()


def cap_ant_in_paper_profile(params: Path) -> None:
    """Give the paper profile the per-env budget it held until Ant's 1e7 runs landed: Ant at 1e6, the others their own."""
    head, profiles = params.read_text().split("\nprofiles:", 1)
    paper_at = profiles.index("\n  paper:")
    paper_section = profiles[paper_at:].replace("    total_timesteps: null", "    total_timesteps: {Ant-v5: 1000000}", 1)
    assert paper_section != profiles[paper_at:], "the paper profile's budget line moved: update this helper"
    params.write_text(head + "\nprofiles:" + profiles[:paper_at] + paper_section)


def test_a_profile_budget_may_cap_one_env(params):
    """A per-env mapping leaves the other envs their own budget, and the captions say which env differs."""
    cap_ant_in_paper_profile(params)
    use_profile("paper", params)
    paper = load_run_config(params)
    assert paper.budget("Ant-v5") == 1_000_000 and paper.budget("HalfCheetah-v5") is None
    assert "the paper's (except Ant-v5 1,000,000)" in paper.budget_caption()


def test_a_profile_switch_rewrites_the_run_section_only(params):
    """Comments and the other sections stay byte for byte: the switch must not destroy what people wrote."""
    before = params.read_text()
    use_profile("tiny", params)
    use_profile(load_run_config(REPO / "params.yaml").profile, params)
    assert params.read_text() == before
    use_profile("tiny", params)
    after = params.read_text()
    comments = [line for line in before.splitlines() if line.lstrip().startswith("#")]
    assert comments and all(line in after.splitlines() for line in comments)
    assert after.split("\nprofiles:", 1)[1] == before.split("\nprofiles:", 1)[1]


def test_params_hyperparameters_match_the_packaged_paper_table():
    """The packaged table is the newest recipe: `retraining`'s where an env is being retrained, else `hyperparameters`."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    newest = {**params["hyperparameters"], **(params.get("retraining") or {})}
    for env_id, hp in newest.items():
        assert hp == paper_hyperparameters(env_id), env_id


@pytest.mark.parametrize("edit,match", [
    (lambda p: p.update(retraining={"Hopper-v5": {}}), r"retraining: unknown env\(s\) \['Hopper-v5'\]"),
    (lambda p: p.update(retraining={"Swimmer-v5": p["hyperparameters"]["Swimmer-v5"]}),
     "retraining.Swimmer-v5 equals hyperparameters.Swimmer-v5: the recipe has landed"),
    (lambda p: p.update(retraining={"Swimmer-v5": {"n_envs": 4}}), "retraining.Swimmer-v5 lacks"),
])
def test_a_bad_retraining_entry_is_refused(params, edit, match):
    data = yaml.safe_load(params.read_text())
    edit(data)
    params.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ValueError, match=match):
        load_run_config(params)


@pytest.mark.parametrize("edit,match", [
    (lambda p: p["run"].update(profile="huge"), "unknown profile 'huge'"),
    (lambda p: p["run"].update(envs=["Hopper-v5"]), "unknown env 'Hopper-v5'"),
    (lambda p: p["run"].update(methods=["bayes"]), "unknown method 'bayes'"),
    (lambda p: p["run"].update(seeds=[]), "seeds must be a non-empty list"),
    (lambda p: p["run"].update(seeds={"MuJoCo": [0, 1]}), r"seeds lacks \['Atari'\]"),
    (lambda p: p["run"].update(seeds={"MuJoCo": [0], "Atari": [0], "Box2D": [0]}), r"unknown env family"),
    (lambda p: p["run"].update(seeds={"MuJoCo": [0], "Atari": []}), "seeds.Atari must be a non-empty list"),
    (lambda p: p["run"].update(n_id_states=0), "n_id_states must be a positive integer"),
    (lambda p: p["run"].pop("eval_episodes"), "lacks"),
    (lambda p: p["run"].update(total_timesteps={"Hopper-v5": 1000}), "total_timesteps names unknown env 'Hopper-v5'"),
    (lambda p: p["run"].update(total_timesteps={"Ant-v5": 0}), "total_timesteps.Ant-v5"),
    (lambda p: p.update(atari_head={"root": 3}), "atari_head.root must be null or a folder"),
    (lambda p: p.update(atari_head={"path": "head"}), "`atari_head` must be a mapping with the one key `root`"),
])
def test_bad_params_name_the_file_and_the_fix(params, edit, match):
    data = yaml.safe_load(params.read_text())
    edit(data)
    params.write_text(yaml.safe_dump(data))
    with pytest.raises(ValueError, match=match) as err:
        load_run_config(params)
    assert str(params) in str(err.value)


def test_an_atari_head_root_is_read_relative_to_params_yaml(params):
    assert load_run_config(params).atari_head_root is None  # the committed default: game-state OOD sources
    data = yaml.safe_load(params.read_text())
    data["atari_head"] = {"root": "data/atari_head"}
    params.write_text(yaml.safe_dump(data))
    assert load_run_config(params).atari_head_root == params.parent / "data" / "atari_head"


def test_unknown_profile_switch_fails_and_keeps_the_file(params):
    before = params.read_text()
    with pytest.raises(ValueError, match="unknown profile"):
        use_profile("huge", params)
    assert params.read_text() == before


def test_checkpoint_trained_for_another_method_is_rejected(tmp_path):
    out = train_run("CartPole-v1", "ensemble", 0, tmp_path / "ckpt", total_timesteps=128,
                    agent_kwargs={"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}})
    assert {p.name for p in out.iterdir()} == {"model.zip", "config.json", "training_curve.csv"}
    assert load_checkpoint(out, "CartPole-v1", "ensemble", 0).config["method"] == "ensemble"
    with pytest.raises(ValueError, match="trained with method='ensemble' but this stage expects 'masksembles'"):
        load_checkpoint(out, "CartPole-v1", "masksembles", 0)
    (out / "model.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="cannot load"):
        load_checkpoint(out, "CartPole-v1", "ensemble", 0)


def test_a_failure_while_writing_leaves_no_half_checkpoint(tmp_path, monkeypatch):
    import pandas as pd

    def disk_full(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(pd.DataFrame, "to_csv", disk_full)  # fails after model.zip was written
    with pytest.raises(OSError, match="disk full"):
        train_run("CartPole-v1", "ensemble", 0, tmp_path / "ckpt", total_timesteps=128,
                  agent_kwargs={"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}})
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == [".ckpt.resume"], "no checkpoint and no temporary folder; only the run's resume point"
    monkeypatch.undo()
    out = train_run("CartPole-v1", "ensemble", 0, tmp_path / "ckpt", total_timesteps=128,
                    agent_kwargs={"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}})
    config = json.loads((out / "config.json").read_text())
    assert config["resumed_from"] == 128 and config["trained_timesteps"] == 128, "the rerun only exported"


def test_normalized_run_saves_and_reloads_its_observation_statistics(tmp_path):
    out = train_run("Walker2d-v5", "masksembles", 0, tmp_path / "ckpt", total_timesteps=256,
                    agent_kwargs={"overrides": {"n_steps": 32, "batch_size": 32, "n_epochs": 1}})
    assert (out / "vecnormalize.pkl").is_file()
    ckpt = load_checkpoint(out, "Walker2d-v5", "masksembles", 0)
    env = ckpt.env(1, seed=0)
    assert env.obs_rms.count > 256 and not env.training, "training statistics, frozen for evaluation"
    (out / "vecnormalize.pkl").unlink()
    with pytest.raises(FileNotFoundError, match="vecnormalize.pkl is missing"):
        load_checkpoint(out, "Walker2d-v5", "masksembles", 0)


def test_committed_checkpoints_pass_the_identity_checks():
    """The checks read model.zip's own policy and algorithm: the real checkpoints must satisfy them."""
    cfg = load_run_config(REPO / "params.yaml")
    checked = 0
    for env_id, method, seed in cfg.runs():
        folder = cfg.checkpoint_dir(env_id, method, seed)
        if (folder / "model.zip").is_file():
            ckpt = load_checkpoint(folder, env_id, method, seed)
            assert (ckpt.vecnormalize_path is not None) == bool(ckpt.config.get("normalize_obs"))
            checked += 1
    assert checked > 0, "the active profile has committed checkpoints"


def test_each_algorithm_is_recognized_from_its_own_zip(tmp_path):
    """SB3 saves attributes, not the class: PPO, A2C and TRPO zips are told apart by their settings."""
    from paper_lib import make_agent

    overrides = {"ppo": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}, "a2c": {"n_steps": 8},
                 "trpo": {"n_steps": 16, "batch_size": 32}}
    for algo, settings in overrides.items():
        folder = tmp_path / algo
        folder.mkdir()
        model = make_agent(algo, "ensemble", "CartPole-v1", 0, overrides=settings)
        model.save(folder / "model.zip")
        (folder / "config.json").write_text(json.dumps(model.paper_lib_config))
        assert type(load_checkpoint(folder, "CartPole-v1", "ensemble", 0).model) is type(model)
        for other in set(overrides) - {algo}:
            (folder / "config.json").write_text(json.dumps({**model.paper_lib_config, "algo": other}))
            with pytest.raises(ValueError, match=f"algorithm '{algo}' \\(config.json: '{other}'\\)"):
                load_checkpoint(folder, "CartPole-v1", "ensemble", 0)


def test_queue_lists_the_training_line_of_each_missing_run_seed_major(params):
    """`pipeline_status queue`: what `make retrain` would train, as resumable lines, seed 0 of every env first."""
    from paper_lib.pipeline.status import queue_lines

    cap_ant_in_paper_profile(params)
    use_profile("paper", params)
    cfg = load_run_config(params)
    lines = queue_lines(cfg, resume_root="/tmp/resume", envs=["Ant-v5", "Swimmer-v5"], methods=["baseline", "ensemble"])
    assert len(lines) == 2 * 2 * len(cfg.seeds_for("Ant-v5"))
    assert [line.split()[7] for line in lines[:4]] == ["0"] * 4, "every seed-0 run comes first"
    ant = [line for line in lines if " Ant-v5 " in line]
    assert all(line.startswith("env PAPER_LIB_RESUME_ROOT=/tmp/resume ") and line.endswith("--timesteps 1000000")
               for line in ant), "Ant gets the profile's own budget for it"
    assert not any("--timesteps" in line for line in lines if " Swimmer-v5 " in line)
    with pytest.raises(ValueError, match=r"env\(s\) \['Foo'\] are not in profile 'paper'"):
        queue_lines(cfg, envs=["Foo"])


def test_a_profile_switch_from_the_command_line_rewrites_runs_yaml_for_dvc(tmp_path):
    """dvc.yaml's per-run stages come from runs.yaml: after `config use`, they are the new profile's runs."""
    import subprocess
    import sys

    (tmp_path / "params.yaml").write_text((REPO / "params.yaml").read_text())
    (tmp_path / "runs.yaml").write_text((REPO / "runs.yaml").read_text())
    assert yaml.safe_load((tmp_path / "runs.yaml").read_text())["profile"] == "paper"
    done = subprocess.run([sys.executable, "-m", "paper_lib.pipeline.config", "use", "tiny"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    listed = yaml.safe_load((tmp_path / "runs.yaml").read_text())
    assert listed["profile"] == "tiny" and not listed["committed_runs"]  # no tiny checkpoint in this folder
    assert "runs.yaml now lists profile 'tiny'" in done.stdout


def test_every_params_section_names_its_unknown_and_missing_keys_alike(tmp_path):
    """One key check (`check_keys`) for every section of params.yaml: the same message wherever the typo is."""
    from paper_lib.experiments.ensembles import load_ensembles_config
    from paper_lib.guard.settings import load_settings
    from paper_lib.pipeline.config import check_keys
    from paper_lib.study.config import load_study_config
    from paper_lib.study.scaling import load_scaling_config

    assert check_keys({"a": 1}, "here", ("a", "b")) == {"a": 1}
    with pytest.raises(ValueError, match=r"^here: unknown key\(s\) \['c'\]; known: \['a', 'b'\]$"):
        check_keys({"a": 1, "c": 2}, "here", ("a", "b"))
    with pytest.raises(ValueError, match=r"^here lacks \['b'\]; fix it$"):
        check_keys({"a": 1}, "here", ("a", "b"), ("a", "b"), fix="fix it")
    with pytest.raises(ValueError, match=r"^here must be a mapping"):
        check_keys([1], "here", ("a",))
    base = yaml.safe_load((REPO / "params.yaml").read_text())
    for name, edit, load in (
            ("guard", lambda p: p["guard"].update(alpah=0.1), load_settings),
            ("ensembles", lambda p: p["ensembles"]["rule"].update(budget_fractoin=0.5), load_ensembles_config),
            ("study", lambda p: p["study"]["objective"].update(measur="x"), load_study_config),
            ("scaling", lambda p: p["study"]["scaling"]["cpu"].update(widht=[64]), load_scaling_config),
            ("run", lambda p: p["run"].update(n_id_state=5), load_run_config)):
        params = yaml.safe_load(yaml.safe_dump(base))
        edit(params)
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(params, sort_keys=False))
        with pytest.raises(ValueError, match=rf"^{path}: .*unknown (key|setting)\(s\) \['\w+'\]; known: \["):
            load(path)
