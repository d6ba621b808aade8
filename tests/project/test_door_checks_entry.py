"""Issue 41, entry points: each bad destination or input is one clear error before any long work, and nothing on disk
changes (the user's files keep their bytes; no temporary is left; nothing of the user's is moved or deleted)."""

from __future__ import annotations

import errno
import hashlib
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import numpy as np
import pytest
import yaml

from paper_lib.common import io
from paper_lib.common.io import (TEMP_MARKER, DestinationError, atomic_dir, atomic_files, recover_dir,
                                 remove_stale_temps, write_text_atomic)

REPO = Path(__file__).resolve().parents[2]
#: CartPole's paper hyperparameters cut to 16 x 8 = 128 steps per rollout, one epoch: a run of 512 steps takes seconds.
TINY_HP = ["--hp", "algo.n_steps=16", "--hp", "algo.batch_size=32", "--hp", "algo.n_epochs=1"]


def snapshot(folder: Path) -> dict[str, str]:
    """Every entry under `folder`, hidden ones too: a file's SHA-256 and mode, a folder's mode, a link's target."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            path = Path(root) / name
            key = str(path.relative_to(folder))
            if path.is_symlink():
                out[key] = f"link {os.readlink(path)}"
            elif path.is_dir():
                out[key] = f"dir {oct(path.stat().st_mode)}"
            else:
                out[key] = f"{hashlib.sha256(path.read_bytes()).hexdigest()} {oct(path.stat().st_mode)}"
    return out


def cli(module: str, *args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)


def params_copy(folder: Path, edit=lambda text: text) -> Path:
    """The project's params.yaml, edited as text, in `folder`."""
    path = folder / "params.yaml"
    path.write_text(edit((REPO / "params.yaml").read_text()))
    return path


def with_tiny_run(text: str) -> str:
    """params.yaml with the tiny profile active (what `config use tiny` writes)."""
    params = yaml.safe_load(text)
    params["run"] = {"profile": "tiny", **params["profiles"]["tiny"]}
    return yaml.safe_dump(params, sort_keys=False)


# ----------------------------------------------------------------------------- 1. a file where a folder goes


def test_training_into_a_file_is_refused_at_the_door_and_the_file_is_kept(tmp_path):
    out = tmp_path / "OUT"
    out.write_bytes(b"the user's own file\n")
    before = snapshot(tmp_path)
    for _ in range(2):  # the second run used to delete the first one's hidden temp: the moved file
        done = cli("paper_lib.agents.training", "CartPole-v1", "baseline", "0", str(out), "--timesteps", "128",
                   *TINY_HP, cwd=tmp_path)
        assert done.returncode == 2, done.stderr
        assert re.search(r"checkpoint folder .*OUT exists and is a file, not a folder; move the file away", done.stderr)
        assert snapshot(tmp_path) == before  # no resume point written: refused before any training
    assert out.read_bytes() == b"the user's own file\n"


def test_training_into_a_foreign_folder_is_refused(tmp_path):
    out = tmp_path / "notes"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    before = snapshot(tmp_path)
    done = cli("paper_lib.agents.training", "CartPole-v1", "baseline", "0", str(out), "--timesteps", "128", *TINY_HP,
               cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert re.search(r"holds files but no checkpoint or resume point .* give a new or empty folder", done.stderr)
    assert snapshot(tmp_path) == before


def test_atomic_dir_refuses_a_file_and_never_touches_unmarked_siblings(tmp_path):
    """Only temporaries atomic_dir made (they hold the marker) are deleted or put back; the user's look-alikes stay."""
    target = tmp_path / "ckpt"
    target.write_text("a file of the user's")
    with pytest.raises(DestinationError, match=r"ckpt exists and is a file, not a folder"):
        with atomic_dir(target):
            pytest.fail("the block must not run")
    assert target.read_text() == "a file of the user's"
    target.unlink()
    (tmp_path / ".ckpt.ab12cd34.tmp").mkdir()  # named like a temp of ours, but unmarked: the user's
    (tmp_path / ".ckpt.ab12cd34.tmp" / "data.csv").write_text("1,2\n")
    (tmp_path / ".ckpt.old").mkdir()  # named like an interrupted swap's old copy, unmarked: the user's
    (tmp_path / ".ckpt.old" / "keep.txt").write_text("mine")
    (tmp_path / ".ckpt.backup").write_text("mine too")
    user = snapshot(tmp_path)
    recover_dir(target)
    assert not target.exists()  # an unmarked .ckpt.old is not moved in (and then replaced) as if it were ours
    stale = tmp_path / ".ckpt.zz99yy88.tmp"  # a temp a killed atomic_dir left: it holds the marker
    stale.mkdir()
    (stale / TEMP_MARKER).write_text(io._MARKER_TEXT)
    assert remove_stale_temps(target) == [stale] and not stale.exists()
    with atomic_dir(target) as tmp:
        (tmp / "model.zip").write_text("new")
    assert [p.name for p in target.iterdir()] == ["model.zip"]  # the marker does not go in with the folder
    assert {k: v for k, v in snapshot(tmp_path).items() if not k.startswith("ckpt")} == user


def test_the_swap_without_an_atomic_exchange_is_recovered_only_from_its_own_marked_copy(tmp_path, monkeypatch):
    """File systems without renameat2: the old folder goes aside marked, so a kill between the renames is undone."""
    monkeypatch.setattr(io, "_exchange", lambda a, b: False)
    target = tmp_path / "ckpt"
    for text in ("old", "new"):
        with atomic_dir(target) as tmp:
            (tmp / "a").write_text(text)
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt"] and os.listdir(target) == ["a"]
    real_rename, calls = os.rename, []

    def killed_at_the_second_rename(src, dst):
        calls.append(src)
        if len(calls) == 2:
            raise KeyboardInterrupt  # the kill, after the old folder went aside and before the new one went in
        real_rename(src, dst)

    monkeypatch.setattr(os, "rename", killed_at_the_second_rename)
    with pytest.raises(KeyboardInterrupt):
        with atomic_dir(target) as tmp:
            (tmp / "a").write_text("newer")
    monkeypatch.setattr(os, "rename", real_rename)
    assert not target.exists() and io.is_ours(tmp_path / ".ckpt.old")
    recover_dir(target)
    assert os.listdir(target) == ["a"] and (target / "a").read_text() == "new"  # whole, and without the marker


# ----------------------------------------------------------------------------- 2. a smaller budget into a bigger run


def test_a_smaller_budget_into_a_bigger_run_is_refused(tmp_path):
    from paper_lib.agents.training import train_run

    out = tmp_path / "ckpt"
    tiny = {"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}}  # as TINY_HP: 128 steps per rollout
    train_run("CartPole-v1", "baseline", 0, out, total_timesteps=500, agent_kwargs=tiny)  # ends at 512: 4 rollouts
    train_run("CartPole-v1", "baseline", 0, out, total_timesteps=500, agent_kwargs=tiny)  # the overshoot is no reason
    os.rename(out, tmp_path / "aside")  # a run killed after its last resume point: the resume point alone
    before = snapshot(tmp_path)
    smaller = cli("paper_lib.agents.training", "CartPole-v1", "baseline", "0", str(out), "--timesteps", "128",
                  *TINY_HP, cwd=tmp_path)
    assert smaller.returncode == 2, smaller.stderr
    assert re.search(r"resume point .*\.ckpt\.resume holds 512 steps, asked 128 .*use a new folder, or --no-resume",
                     smaller.stderr)
    assert snapshot(tmp_path) == before
    os.rename(tmp_path / "aside", out)
    shutil.rmtree(tmp_path / ".ckpt.resume")  # the finished run alone
    before = snapshot(tmp_path)
    smaller = cli("paper_lib.agents.training", "CartPole-v1", "baseline", "0", str(out), "--timesteps", "128",
                  *TINY_HP, cwd=tmp_path)
    assert smaller.returncode == 2, smaller.stderr
    assert re.search(r"ckpt holds a finished run of 500 steps, asked 128; use a new folder, or --no-resume",
                     smaller.stderr)
    assert snapshot(tmp_path) == before
    again = cli("paper_lib.agents.training", "CartPole-v1", "baseline", "0", str(out), "--timesteps", "500",
                *TINY_HP, cwd=tmp_path)  # the same run, finished: a queue that reaches it again changes nothing
    assert again.returncode == 0 and "already holds this run, finished at 500 steps: nothing to do" in again.stderr
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- 3. an unknown notebook parameter


def _notebook_with_parameters(folder: Path, parameters: str) -> None:
    """folder/nb.ipynb: a `parameters` cell, then a cell that leaves executed.txt (so a run that started shows)."""
    nb = nbformat.v4.new_notebook(metadata={"kernelspec": {"name": "python3", "display_name": "Python 3",
                                                           "language": "python"}})
    params = nbformat.v4.new_code_cell(parameters)
    params.metadata["tags"] = ["parameters"]
    nb.cells = [params, nbformat.v4.new_code_cell("open('executed.txt', 'w').write('ran')")]
    nbformat.write(nb, folder / "nb.ipynb")


def test_an_unknown_notebook_parameter_is_an_error_before_anything_runs(tmp_path):
    _notebook_with_parameters(tmp_path, "alpha = 1\nlabel = 'x'")
    before = snapshot(tmp_path)
    done = cli("paper_lib.pipeline.notebook_run", "nb.ipynb", "out.ipynb", "-p", "bogus", "3", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert re.search(r"unknown parameter\(s\) of nb\.ipynb, got -p bogus; its parameters are alpha, label: fix the "
                     r"name \(nothing was executed\)", done.stderr)
    assert snapshot(tmp_path) == before  # neither executed.txt (a cell ran) nor out.ipynb


def test_a_notebook_parameter_of_the_wrong_kind_is_an_error_naming_it_before_anything_runs(tmp_path):
    """`-p alpha abc` where alpha's default is 1: refused by name, not failing later in some cell with another cause."""
    _notebook_with_parameters(tmp_path, "alpha = 1\nscale = 0.5\nlabel = 'x'\nwhere = None")
    before = snapshot(tmp_path)
    done = cli("paper_lib.pipeline.notebook_run", "nb.ipynb", "out.ipynb", "-p", "alpha", "abc", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert re.search(r"parameter alpha of nb\.ipynb takes an int \(default 1\), got 'abc'; give an int "
                     r"\(nothing was executed\)", done.stderr)
    assert snapshot(tmp_path) == before
    ok = cli("paper_lib.pipeline.notebook_run", "nb.ipynb", "out.ipynb", "-p", "scale", "2", "-p", "where", "abc",
             cwd=tmp_path)  # an int for a float default, anything for a None default
    assert ok.returncode == 0, ok.stderr


# ----------------------------------------------------------------------------- 4. evaluate_agent's --out


TINY_BUDGET = dict(configs=2, steps_per_config=10, id_episodes=4, skip_first=2, max_episode_steps=20, n_bootstrap=20,
                   n_scoring_seeds=2)


@pytest.fixture(scope="module")
def plain_zip(tmp_path_factory) -> Path:
    """An untrained SB3 PPO for HalfCheetah: the benchmark accepts any SB3 zip."""
    from stable_baselines3 import PPO

    from paper_lib.agents.envs import make_env

    path = tmp_path_factory.mktemp("agent") / "plain.zip"
    PPO("MlpPolicy", make_env("HalfCheetah-v5", 1, seed=0), n_steps=32, batch_size=32, seed=0).save(path)
    return path


def test_evaluate_agent_checks_its_out_path_before_collecting(tmp_path, plain_zip):
    out = tmp_path / "results.txt"
    out.write_text("not a folder")
    before = snapshot(tmp_path)
    done = cli("paper_lib.pipeline.evaluate_agent", str(plain_zip), "HalfCheetah-v5", "--out", str(out),
               cwd=tmp_path, timeout=90)  # the default budget collects for minutes: only a check at the door is fast
    assert done.returncode == 2, done.stderr
    assert re.search(r"--out folder .*results\.txt is a file, not a folder; give a folder path", done.stderr)
    assert snapshot(tmp_path) == before


def test_evaluate_agent_refuses_a_read_only_out_folder_before_collecting(tmp_path, plain_zip, monkeypatch, capsys):
    from paper_lib.pipeline import evaluate_agent

    out = tmp_path / "read_only"
    out.mkdir()
    out.chmod(0o555)
    if os.geteuid() == 0:  # root writes anywhere: let os.access report what the mode bits say
        real_access = os.access
        monkeypatch.setattr(os, "access", lambda p, mode, **kw: Path(p) != out and real_access(p, mode, **kw))

    def collection_started(*args, **kwargs):
        raise AssertionError("the collection started before --out was checked")

    monkeypatch.setattr(evaluate_agent, "collect_id_states", collection_started)
    before = snapshot(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        evaluate_agent.main([str(plain_zip), "HalfCheetah-v5", "--out", str(out)])
    assert exit_info.value.code == 2
    assert re.search(r"--out folder .*read_only: the folder .*read_only is read-only; give a folder you can write",
                     capsys.readouterr().err)
    assert snapshot(tmp_path) == before
    out.chmod(0o755)


@pytest.mark.parametrize("failing", ["ood_metrics.md", "roc.csv"])
def test_a_write_failing_part_way_leaves_the_last_runs_files_whole(tmp_path, plain_zip, monkeypatch, failing):
    """A full disk while writing run B: the folder still holds run A's files only, nothing of B, no temporary."""
    from paper_lib.pipeline import evaluate_agent as module
    from paper_lib.reporting import tables

    out = tmp_path / "out"
    (tmp_path / "out").mkdir()
    (out / "notes.txt").write_text("the user's, beside the results")
    module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=0, out_dir=out)
    before = snapshot(tmp_path)
    for owner in (tables, module):  # save_table's writes and roc.csv's
        real = owner.write_text_atomic

        def disk_full(path, text, real=real):
            if Path(path).name == failing:
                raise OSError(errno.ENOSPC, "No space left on device")
            return real(path, text)

        monkeypatch.setattr(owner, "write_text_atomic", disk_full)
    with pytest.raises(module.OutputWriteError, match=r"writing the results to .*out failed, got OSError: .*No space "
                                                      r"left.*none of them was moved in"):
        module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=1, out_dir=out)
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- 5. params.yaml


def test_a_duplicate_key_in_params_yaml_is_named_with_file_and_line(tmp_path):
    def duplicate(text: str) -> str:
        return text.replace("  tiny:\n    envs: [HalfCheetah-v5]\n", "  tiny:\n    envs: [HalfCheetah-v5]\n"
                                                                     "    eval_episodes: 3\n", 1)

    path = params_copy(tmp_path, duplicate)
    lines = path.read_text().splitlines()
    first = lines.index("    eval_episodes: 3") + 1
    second = next(i + 1 for i, line in enumerate(lines) if i + 1 > first and line.strip().startswith("eval_episodes"))
    before = snapshot(tmp_path)
    for command in (["show"], ["use", "tiny"]):
        done = cli("paper_lib.pipeline.config", *command, cwd=tmp_path)
        assert done.returncode == 2, done.stderr
        assert re.search(rf"params\.yaml line {second}: duplicate key 'eval_episodes', got it on lines {first} and "
                         rf"{second} .*delete one of them", done.stderr), done.stderr
    assert snapshot(tmp_path) == before


def test_the_ensembles_section_reads_params_yaml_with_the_same_duplicate_key_check(tmp_path):
    """paper_lib.experiments.ensembles reads params.yaml through the pipeline's one reader, not plain YAML."""
    from paper_lib.experiments.ensembles import load_ensembles_config

    path = params_copy(tmp_path, lambda text: text.replace("  rule: {", "  rule: {budget_fraction: 0.5, ", 1))
    assert "rule: {budget_fraction: 0.5, budget_fraction" in path.read_text()
    with pytest.raises(ValueError, match=r"params\.yaml line \d+: duplicate key 'budget_fraction'"):
        load_ensembles_config(path)


def test_use_on_a_read_only_params_yaml_is_one_error_and_the_file_is_unchanged(tmp_path):
    path = params_copy(tmp_path)
    path.chmod(0o444)
    before = snapshot(tmp_path)
    done = cli("paper_lib.pipeline.config", "use", "tiny", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert re.fullmatch(r"error: params\.yaml is read-only, got mode -r--r--r--; make it writable \(chmod u\+w "
                        r"params\.yaml\) and run again \(params\.yaml was left unchanged\)\n", done.stderr)
    assert snapshot(tmp_path) == before


def test_config_show_names_the_keys_of_run_edited_away_from_its_profile(tmp_path):
    def edit_run(text: str) -> str:
        params = yaml.safe_load(text)
        profile = params["run"]["profile"]
        params["run"]["eval_episodes"] = params["profiles"][profile]["eval_episodes"] + 1
        params["run"]["seeds"] = [0]  # the profile's: a list, or one per env family (the paper profile's)
        return yaml.safe_dump(params, sort_keys=False)

    path = params_copy(tmp_path, edit_run)
    profile = yaml.safe_load(path.read_text())["run"]["profile"]
    before = snapshot(tmp_path)
    done = cli("paper_lib.pipeline.config", "show", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert re.search(rf"`run` differs from profiles\.{profile} in eval_episodes, seeds:\n  eval_episodes: run has \d+, "
                     rf"profiles\.{profile} has \d+\n", done.stdout), done.stdout
    assert f"config use {profile}` makes run its copy again" in done.stdout
    assert snapshot(tmp_path) == before
    from paper_lib.pipeline.config import run_differences

    assert run_differences(yaml.safe_load(with_tiny_run(path.read_text()))) == []  # run as `use` writes it: no note


# ----------------------------------------------------------------------------- 6. guard seeds the profile lacks


@pytest.mark.parametrize("profile", ["tiny", "paper"])
def test_guard_budget_seeds_must_be_seeds_of_their_profile(tmp_path, profile):
    from paper_lib.guard.settings import load_settings

    def seed_seven(text: str) -> str:
        params = yaml.safe_load(with_tiny_run(text))
        params["guard"]["budgets"][profile]["seeds"] = [7]  # tiny: the active profile; paper: another one
        return yaml.safe_dump(params, sort_keys=False)

    path = params_copy(tmp_path, seed_seven)
    before = snapshot(tmp_path)
    from paper_lib.pipeline.config import seeds_of

    seeds = seeds_of(yaml.safe_load(path.read_text())["profiles"][profile]["seeds"])
    with pytest.raises(ValueError, match=rf"params\.yaml: guard\.budgets\.{profile}: seeds must be seeds of profile "
                                         rf"'{profile}', got \[7\] \(its runs have seeds {re.escape(str(seeds))}\)"):
        load_settings(path)
    assert snapshot(tmp_path) == before


def test_notebook_8_with_a_bad_guard_budget_stops_in_its_first_cell_naming_the_key(tmp_path):
    """Another profile's budget too: `config use` would switch to it. The notebook reads params.yaml first."""
    def negative(text: str) -> str:
        params = yaml.safe_load(with_tiny_run(text))
        params["guard"]["budgets"]["paper"]["fit_episodes"] = -10  # tiny is active
        return yaml.safe_dump(params, sort_keys=False)

    path = params_copy(tmp_path, negative)
    target = tmp_path / "08_guard.ipynb"
    before = snapshot(tmp_path)
    done = cli("paper_lib.pipeline.notebook_run", str(REPO / "notebooks/08_guard.ipynb"), str(target), "-p",
               "params_file", str(path), cwd=REPO, timeout=300)
    assert done.returncode == 1, done.stderr[-2000:]
    assert f"ValueError: {path}: guard.budgets.paper.fit_episodes must be an integer >= 1, got -10" in done.stderr
    assert f"08_guard.ipynb failed in a cell (traceback above); {target} was not written" in done.stderr
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- 7. scaling runs listed twice


def test_scaling_methods_listed_twice_are_refused_naming_params_yaml(tmp_path):
    def twice(text: str) -> str:
        params = yaml.safe_load(text)
        section = params["study"]["scaling"]["tiny"]
        section["methods"] = section["methods"] + section["methods"][:1]
        return yaml.safe_dump(params, sort_keys=False)

    path = params_copy(tmp_path, twice)
    before = snapshot(tmp_path)
    done = cli("paper_lib.study.scaling", "--params", str(path), "--profile", "tiny", "--list", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert re.search(rf"{re.escape(str(path))}: study\.scaling\.tiny\.methods must list each entry once, got "
                     rf"\['baseline'\] twice .*delete the repeats in {re.escape(str(path))}", done.stderr), done.stderr
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- 8. Guard.save, a garbage study .db


def test_guard_save_onto_a_file_is_a_clear_error(tmp_path):
    from stable_baselines3 import PPO

    from paper_lib.guard.core import GUARDS_DIR, Guard
    from paper_lib.guard.scores import CallableScore

    guard = Guard.from_scores(PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu"),
                              CallableScore(lambda s: s[:, 0], "pole_x"), np.arange(20.0), 0.1)
    taken = tmp_path / "taken"
    taken.write_text("a file, not a folder")
    before = snapshot(tmp_path)
    with pytest.raises(DestinationError, match=r"Guard\.save: folder .*taken is a file, not a folder"):
        guard.save(taken)
    assert snapshot(tmp_path) == before
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / GUARDS_DIR).write_text("a file where the guards go")
    before = snapshot(tmp_path)
    with pytest.raises(DestinationError, match=r"Guard\.save: guard folder .*run/guards/.* lies under .*guards, "
                                               r"which is a file"):
        guard.save(tmp_path / "run")
    assert snapshot(tmp_path) == before


def test_a_garbage_study_database_is_one_error_naming_the_file(tmp_path):
    from paper_lib.study.config import load_study_config

    path = params_copy(tmp_path, with_tiny_run)
    study = list(load_study_config(path).studies)[0]
    db = tmp_path / "studies.db"
    db.write_text("this is a text file, not SQLite\n")
    before = snapshot(tmp_path)
    done = cli("paper_lib.study.worker", "--params", str(path), "--study", study, "--storage", f"sqlite:///{db}",
               cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert re.fullmatch(rf"error: study storage {re.escape(str(db))} is not an SQLite database, got a file starting "
                        r"with b'this is a text f'; move it aside \(it was left as it is\) or give another \.db file\n",
                        done.stderr), done.stderr
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- the writers themselves


def test_atomic_files_moves_nothing_when_the_block_fails(tmp_path):
    (tmp_path / "a.csv").write_text("run A")
    before = snapshot(tmp_path)
    with pytest.raises(OSError, match="disk full"):
        with atomic_files(tmp_path) as stage:
            write_text_atomic(stage / "a.csv", "run B")
            raise OSError("disk full")
    assert snapshot(tmp_path) == before
    with atomic_files(tmp_path) as stage:
        write_text_atomic(stage / "a.csv", "run B")
        write_text_atomic(stage / "b.csv", "run B")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv"] and (tmp_path / "a.csv").read_text() == "run B"


OLD_SET = {"a.csv": "old a", "b.csv": "old b", "notes.txt": "the user's"}
NEW_SET = {"a.csv": "new a", "b.csv": "new b", "c.csv": "new c"}  # c.csv had no old version


def _write_group(folder: Path) -> None:
    with atomic_files(folder) as stage:
        for name, text in NEW_SET.items():
            (stage / name).write_text(text)


def _contents(folder: Path) -> dict[str, str]:
    return {p.name: p.read_text() for p in folder.iterdir()}


def _fail_moves_after_the_first(monkeypatch, fail_put_back: bool = False) -> None:
    """os.replace of atomic_files fails from its second move of a new file on (a disk error part-way through).

    Only the group's moves count (a file from the stage into the folder), not the atomic writes inside the stage."""
    real, moves = os.replace, []

    def replace(src, dst, *args, **kwargs):
        putting_back = Path(src).parent.name == ".paper_lib_old"
        if Path(src).parent.name.startswith(".paper_lib_files."):
            moves.append(src)
            if len(moves) > 1:
                raise OSError(errno.EIO, "Input/output error")
        if putting_back and fail_put_back:
            raise OSError(errno.EIO, "Input/output error")
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(io.os, "replace", replace)


def test_atomic_files_puts_the_old_group_back_when_a_move_fails_part_way(tmp_path, monkeypatch):
    """The first new file is moved in, the second move fails: the old group is whole again, never a mix."""
    for name, text in OLD_SET.items():
        (tmp_path / name).write_text(text)
    before = snapshot(tmp_path)
    _fail_moves_after_the_first(monkeypatch)
    with pytest.raises(OSError, match="Input/output error"):
        _write_group(tmp_path)
    assert snapshot(tmp_path) == before  # a.csv put back, c.csv (new) gone, no stage left
    monkeypatch.undo()
    _write_group(tmp_path)
    assert _contents(tmp_path) == {**NEW_SET, "notes.txt": "the user's"}


def test_atomic_files_left_mixed_by_a_failed_put_back_is_finished_by_the_next_write(tmp_path, monkeypatch):
    for name, text in OLD_SET.items():
        (tmp_path / name).write_text(text)
    _fail_moves_after_the_first(monkeypatch, fail_put_back=True)
    with pytest.raises(io.MixedFilesError, match=r"putting the old ones back failed too .* run "
                                                 r"paper_lib\.common\.io\.recover_files\("):
        _write_group(tmp_path)
    monkeypatch.undo()
    assert [p.name for p in io.recover_files(tmp_path)][0].startswith(".paper_lib_files.")
    assert _contents(tmp_path) == OLD_SET  # the old group whole, the stage gone


KILL_AFTER_FIRST_MOVE = r"""
import os, sys
from pathlib import Path
from paper_lib.common import io
real, moves = os.replace, []
def replace(src, dst, *a, **k):
    moves.append(src)
    if len(moves) == 2:
        os._exit(9)  # killed between two moves: nothing of Python's cleanup runs
    return real(src, dst, *a, **k)
io.os.replace = replace
with io.atomic_files(sys.argv[1]) as stage:
    for name in ("a.csv", "b.csv", "c.csv"):
        (stage / name).write_text("new " + name[0])
"""


def _killed_between_two_moves(tmp_path: Path) -> tuple[Path, subprocess.CompletedProcess[str]]:
    """An output folder holding OLD_SET, and a real process killed between two moves of writing NEW_SET into it."""
    out = tmp_path / "out"
    out.mkdir()
    for name, text in OLD_SET.items():
        (out / name).write_text(text)
    return out, _kill_after_first_move(out)


def _kill_after_first_move(out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", KILL_AFTER_FIRST_MOVE, str(out)], capture_output=True, text=True,
                          timeout=120)


def test_atomic_files_killed_between_two_moves_is_put_back_by_the_next_write(tmp_path):
    out, done = _killed_between_two_moves(tmp_path)
    assert done.returncode == 9, done.stderr
    assert (out / "a.csv").read_text() == "new a" and (out / "b.csv").read_text() == "old b"  # the mix a kill leaves
    assert io.recover_files(out) and _contents(out) == OLD_SET  # the old group whole again, nothing else
    assert io.recover_files(out) == []
    _kill_after_first_move(out)
    _write_group(out)  # a new write first puts the old group back, then moves its own in
    assert _contents(out) == {**NEW_SET, "notes.txt": "the user's"}


def test_evaluate_agent_puts_back_a_group_a_kill_left_mixed_before_collecting(tmp_path, plain_zip, monkeypatch):
    """A kill between two moves left --out mixed; the next evaluate_agent puts the old group back at its door, so a
    collection that then fails (here: injected) leaves the old group whole, not the mix."""
    from paper_lib.pipeline import evaluate_agent as module

    out, done = _killed_between_two_moves(tmp_path)
    assert done.returncode == 9 and (out / "a.csv").read_text() == "new a", done.stderr

    def collection_fails(*args, **kwargs):
        raise RuntimeError("the collection crashed")

    monkeypatch.setattr(module, "collect_id_states", collection_fails)
    with pytest.raises(RuntimeError, match="the collection crashed"):
        module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=0, out_dir=out)
    assert _contents(out) == OLD_SET


def test_evaluate_agent_says_how_to_finish_when_the_old_results_cannot_be_put_back(tmp_path, plain_zip, monkeypatch):
    """The moves fail part-way and so does putting the old files back: the error says so (not 'as it was') and how
    to finish, and the next run puts the old group back before it writes. (A folder of the user's files too: one of
    evaluate_agent's files only is swapped whole, with no moves to fail part-way.)"""
    from paper_lib.pipeline import evaluate_agent as module

    out = tmp_path / "out"
    module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=0, out_dir=out)
    (out / "notes.txt").write_text("the user's")
    first = {name: (out / name).read_bytes() for name in module.OUTPUT_FILES}
    _fail_moves_after_the_first(monkeypatch, fail_put_back=True)
    expected = r"^moving the files into .*out failed part-way .* putting the old ones back failed too .* run " \
               r"paper_lib\.common\.io\.recover_files"
    with pytest.raises(module.OutputWriteError, match=expected) as err:
        module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=1, out_dir=out)
    assert "as it was" not in str(err.value)  # it is not: some results are new, the rest old, until recovered
    monkeypatch.undo()
    assert io.recover_files(out)
    assert {name: (out / name).read_bytes() for name in module.OUTPUT_FILES} == first


# ----------------------------------------------------------------------------- 9. the README paste and the site (issue 71)

def _readme_inputs(to: Path) -> str:
    """The committed README, docs and the results readme_results.py pastes from, in `to`; the active profile."""
    sys.path.insert(0, str(REPO / "scripts"))
    import readme_results

    profile = readme_results.active_profile()
    shutil.copy(REPO / "README.md", to / "README.md")
    shutil.copytree(REPO / "docs", to / "docs")
    for part in (f"results/{profile}/tables", "results/bench", "results/recipe_probes"):
        shutil.copytree(REPO / part, to / part)
    shutil.copy(REPO / f"results/{profile}/runs.md", to / f"results/{profile}/runs.md")
    return profile


@pytest.mark.parametrize("damage,match", [
    (lambda p: p.write_text(p.read_text()[: len(p.read_text()) // 2]),
     r"rewards\.md is incomplete \(cut off\?\): its table has a row cut short or no header; run the stage that "
     r"writes it again \(`make reproduce`, or `git checkout results/\w+/tables/rewards\.md` for the committed copy\): "
     r"nothing was written"),
    (lambda p: p.write_text("".join(p.read_text().splitlines(keepends=True)[:5])),  # cut at a row's end
     r"rewards\.md is incomplete \(cut off\?\): its table has 1 rows but rewards\.csv has 18"),
    (lambda p: p.with_suffix(".csv").write_text(p.with_suffix(".csv").read_text()[:-30]),
     r"rewards\.csv is incomplete \(cut off\?\): its last line ends mid-row"),
    (lambda p: p.unlink(), r"rewards\.md is missing; run the stage that writes it again"),
])
def test_readme_results_refuses_a_truncated_or_missing_table_and_writes_nothing(tmp_path, damage, match):
    profile = _readme_inputs(tmp_path)
    damage(tmp_path / "results" / profile / "tables" / "rewards.md")
    before = snapshot(tmp_path)
    run = subprocess.run([sys.executable, str(REPO / "scripts" / "readme_results.py"), profile], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode != 0 and "Traceback" not in run.stderr, run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and re.search(match, run.stderr), run.stderr
    assert snapshot(tmp_path) == before


def _site_workspace(root: Path) -> tuple[object, str, Path]:
    """The site's inputs (dvc.yaml and the executed notebooks of the active profile) in `root`."""
    sys.path.insert(0, str(REPO / "scripts"))
    import build_site

    profile = build_site.active_profile()
    shutil.copy(REPO / "dvc.yaml", root / "dvc.yaml")
    folder = root / "results" / profile / "notebooks"
    shutil.copytree(REPO / "results" / profile / "notebooks", folder)
    return build_site, profile, folder


def test_the_site_refuses_a_missing_notebook_naming_its_stage(tmp_path):
    build_site, profile, folder = _site_workspace(tmp_path)
    (folder / "03_ood_detection.ipynb").unlink()
    before = snapshot(tmp_path)
    with pytest.raises(ValueError, match=rf"results/{profile}/notebooks/03_ood_detection\.ipynb is missing \(the DVC "
                                         r"stage ood writes it\): run `dvc repro ood` or restore the committed copy "
                                         rf"with `git checkout results/{profile}/notebooks/03_ood_detection\.ipynb`; "
                                         r"the site was not built"):
        build_site.notebook_pages(profile, tmp_path)
    assert snapshot(tmp_path) == before


def test_the_site_refuses_a_truncated_notebook_naming_it(tmp_path):
    build_site, profile, folder = _site_workspace(tmp_path)
    page = folder / "00_quickstart.ipynb"
    page.write_bytes(page.read_bytes()[: page.stat().st_size // 2])
    before = snapshot(tmp_path)
    with pytest.raises(ValueError, match=rf"results/{profile}/notebooks/00_quickstart\.ipynb is not a readable "
                                         r"notebook \(cut off\?\) .*run `dvc repro quickstart` or restore the committed "
                                         r"copy .*the site was not built"):
        build_site.notebook_pages(profile, tmp_path)
    assert snapshot(tmp_path) == before


def test_a_page_that_left_the_sources_leaves_the_built_site(tmp_path):
    """Sphinx builds only the pages it has: the previous build's copy of a removed page must go with its source."""
    sys.path.insert(0, str(REPO / "scripts"))
    import build_site

    source, site = tmp_path / "src", tmp_path / "site"
    (source / "notebooks").mkdir(parents=True)
    (site / "notebooks").mkdir(parents=True)
    for folder, name in ((source, "notebooks/99_gone.ipynb"), (site, "notebooks/99_gone.html"),
                         (site, "notebooks/03_ood_detection.html")):
        (folder / name).write_text("old")
    build_site.assemble(source, REPO, site)
    assert not (source / "notebooks" / "99_gone.ipynb").exists() and not (site / "notebooks" / "99_gone.html").exists()
    assert (site / "notebooks" / "03_ood_detection.html").read_text() == "old"  # a page still there is Sphinx's to rebuild


# ----------------------------------------------------------------------------- 10. evaluate_agent's --out as one unit (issue 71)

def test_evaluate_agent_swaps_a_folder_of_its_own_files_in_whole(tmp_path, plain_zip, monkeypatch):
    """A folder holding only the last run's files is replaced as one folder (one atomic exchange, no file moved in
    one by one), so a kill at any instant leaves the old files or the new ones, never a mix."""
    from paper_lib.pipeline import evaluate_agent as module

    out = tmp_path / "out"
    module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=0, out_dir=out)
    first = {name: (out / name).read_bytes() for name in module.OUTPUT_FILES}
    inode = out.stat().st_ino

    def no_group_move(*args, **kwargs):
        raise AssertionError("the files were moved in one by one")

    monkeypatch.setattr(module, "atomic_files", no_group_move)
    module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=1, out_dir=out)
    assert out.stat().st_ino != inode, "the folder was not swapped in whole"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"], "a temporary folder was left beside it"
    assert sorted(p.name for p in out.iterdir()) == sorted(module.OUTPUT_FILES)
    assert (out / "ood_metrics.csv").read_bytes() != first["ood_metrics.csv"]


def test_evaluate_agent_keeps_the_users_files_beside_its_own(tmp_path, plain_zip):
    """A folder that also holds the user's files is never swapped (that would remove them): the group move, whose
    journal puts the old files back after a kill, writes the results beside them."""
    from paper_lib.pipeline import evaluate_agent as module

    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    inode = out.stat().st_ino
    module.evaluate_agent(plain_zip, "HalfCheetah-v5", budget=module.Budget(**TINY_BUDGET), seed=0, out_dir=out)
    assert out.stat().st_ino == inode and (out / "notes.txt").read_text() == "the user's"
    assert sorted(p.name for p in out.iterdir()) == sorted([*module.OUTPUT_FILES, "notes.txt"])
    assert not module.swapped_whole(out) and module.swapped_whole(tmp_path / "new")


# ----------------------------------------------------------------------------- 11. one writer per run output (issue 71)

def _stage_tree(root: Path) -> object:
    """A params.yaml copy whose results live under `root`, a CartPole baseline and masksembles checkpoint each (built,
    not trained), and the baseline's dataset: what the per-run stages read before they take their lock."""
    import dataclasses
    import json

    from paper_lib import make_agent
    from paper_lib.ood.datasets import StateDataset
    from paper_lib.pipeline.config import load_run_config

    cfg = dataclasses.replace(load_run_config(params_copy(root)), root=root)
    tiny = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}
    for method in ("baseline", "masksembles"):
        folder = cfg.checkpoint_dir("CartPole-v1", method, 0)
        folder.mkdir(parents=True)
        model = make_agent("ppo", method, "CartPole-v1", 0, overrides=tiny)
        model.save(folder / "model.zip")
        (folder / "config.json").write_text(json.dumps(model.paper_lib_config))
    StateDataset(states=np.zeros((4, 4), dtype=np.float32), labels=[0, 0, 1, 1], source=["id", "id", "noise", "noise"],
                 config_index=[-1] * 4, episode=[0] * 4, step=[0, 1, 2, 3],
                 metadata={"model": {"env_id": "CartPole-v1", "method": "baseline", "seed": 0}}
                 ).save(cfg.dataset_path("CartPole-v1", "baseline", 0))
    return cfg


@pytest.mark.parametrize("stage,doing", [("evaluate", "evaluating"), ("collect", "collecting"),
                                         ("score", "scoring"), ("common_score", "scoring the common states")])
def test_a_second_writer_of_a_runs_output_stops_at_once_naming_it(tmp_path, stage, doing):
    """Two processes on one run's stage: the second stops before any work (the lock is held here, as the first
    process would), naming the output and the lock; nothing on disk changes."""
    from paper_lib.pipeline import common_states, run_results, stages
    from paper_lib.agents.training import stage_lock
    from paper_lib.pipeline.run_results import evaluation_path, scores_dir

    cfg = _stage_tree(tmp_path)
    method = "masksembles" if stage == "common_score" else "baseline"
    out, call = {
        "evaluate": (evaluation_path(cfg, "CartPole-v1", method, 0), run_results.evaluate_run),
        "collect": (cfg.dataset_path("CartPole-v1", method, 0), stages.collect_run),
        "score": (scores_dir(cfg, "CartPole-v1", method, 0), run_results.score_run_files),
        "common_score": (common_states.common_scores_dir(cfg, "CartPole-v1", method, 0), common_states.score_common_files),
    }[stage]
    with stage_lock(out, "the first process's stage") as lock:
        before = snapshot(tmp_path)
        with pytest.raises(DestinationError, match=rf"^another process is {doing} into {re.escape(str(out))} \(it holds "
                                                   rf"{re.escape(str(lock))}\); wait for it to finish: each run's stage "
                                                   r"runs in one process at a time \(nothing was changed\)$"):
            call(cfg, "CartPole-v1", method, 0)
        assert snapshot(tmp_path) == before
    assert not lock.exists()  # the holder removes its lock file when it lets go
