"""kill -9 at random points of training and of collection: no complete artifact is ever lost.

Each run is a real command line (`python -m paper_lib.agents.training`, `python -m paper_lib.pipeline.stages
collect`) killed with SIGKILL by PID at a seeded random point of its expected CPU time (every
other kill late in the run, where the artifact is written; CPU time, so that the load of the
machine does not move the points). While it runs, the artifact that
existed before must stay in place; after each kill it must still be complete and loadable, and
no half-written file may sit at its path. The next run continues from what the kill left, and
the last one must finish cleanly, leaving no temporary files behind.
"""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO

from paper_lib.agents.training import resume_dir_for
from paper_lib.ood.datasets import StateDataset
from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.stages import train_stage

REPO = Path(__file__).resolve().parents[2]
CHECKPOINT_FILES = {"model.zip", "config.json", "training_curve.csv"}


def cpu_seconds(pid: int) -> float:
    """CPU time a running process has used (Linux /proc): unlike wall time, it does not depend on the load."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def kill_points(rng: np.random.Generator, n: int, cpu: float) -> list[float]:
    """n seeded points in a run of `cpu` CPU seconds; every other one late, where artifacts are written."""
    return [float(rng.uniform(0.6, 0.93) if i % 2 else rng.uniform(0.05, 0.93)) * cpu for i in range(n)]


#: CPU seconds per unit of work vary with the load on the machine (shared caches, SMT siblings, the other
#: xdist worker, training in the background), so a kill point taken as a fraction of one reference run can fall
#: after a later run's end: a fresh-clone `make test` once failed that way. A run that ends unkilled is checked like
#: any other, and the next one is aimed this much earlier, until the wanted number of kills has happened.
EARLIER = 0.6
MAX_RUNS = 8


def kill_until(runs: int, rng: np.random.Generator, cpu: float, start_run, check) -> int:
    """Start runs (`start_run(at_cpu)` -> killed?) at seeded kill points until `runs` were killed; `check()` after each."""
    kills, attempts = 0, 0
    points = iter(kill_points(rng, MAX_RUNS, 1.0))
    while kills < runs:
        attempts += 1
        assert attempts <= MAX_RUNS, f"only {kills} of {MAX_RUNS} runs could be killed before they ended"
        killed = start_run(next(points) * cpu)
        check()
        kills += killed
        cpu *= 1.0 if killed else EARLIER
    return kills


def run_and_kill(cmd: list[str], cwd: Path, at_cpu: float, still_there) -> bool:
    """Start `cmd`, SIGKILL it once it has used `at_cpu` CPU seconds, checking `still_there()` meanwhile.

    Returns True if it was killed; a run that ends on its own before must have succeeded.
    """
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        while proc.poll() is None:
            assert still_there(), "the complete artifact vanished while the run was going"
            try:
                if cpu_seconds(proc.pid) >= at_cpu:
                    proc.send_signal(signal.SIGKILL)
                    proc.wait()
                    return True
            except (FileNotFoundError, ProcessLookupError):  # it has just exited
                pass
            time.sleep(0.01)
        stderr = proc.stderr.read().decode()
        assert proc.returncode == 0, stderr
        return False
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()


def finish(cmd: list[str], cwd: Path) -> float:
    """Run `cmd` to its end; it must succeed. Returns the CPU seconds it used."""
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    stderr = proc.stderr.read().decode()
    proc.stderr.close()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    assert proc.returncode == 0, stderr[-3000:]
    return usage.ru_utime + usage.ru_stime


# ------------------------------------------------------------------------------- training


def assert_complete_checkpoint(out: Path) -> dict:
    """The folder holds exactly a finished checkpoint: every file, a readable config, a whole zip."""
    assert {p.name for p in out.iterdir()} == CHECKPOINT_FILES, sorted(p.name for p in out.iterdir())
    config = json.loads((out / "config.json").read_text())
    with zipfile.ZipFile(out / "model.zip") as archive:
        assert archive.testzip() is None and {"data", "policy.pth"} <= set(archive.namelist())
    return config


def assert_complete_resume_point(folder: Path) -> None:
    if folder.exists():
        with open(folder / "state.pkl", "rb") as f:
            assert pickle.load(f)["num_timesteps"] > 0
        with zipfile.ZipFile(folder / "model.zip") as archive:
            assert archive.testzip() is None


def test_kill_until_aims_earlier_when_runs_end_before_their_kill_point():
    """The flaky case: later runs need half the CPU of the (loaded) reference run. Kills still happen."""
    checked, aimed = [], []

    def start_run(at_cpu: float) -> bool:  # a run that costs 1 CPU second ends unkilled if aimed later
        aimed.append(at_cpu)
        return at_cpu < 1.0

    assert kill_until(2, np.random.default_rng(9), 2.0, start_run, lambda: checked.append(1)) == 2
    assert len(checked) == len(aimed) and aimed[-1] < 1.0 and any(a >= 1.0 for a in aimed)
    with pytest.raises(AssertionError, match="could be killed"):
        kill_until(1, np.random.default_rng(9), 2.0, lambda at_cpu: False, lambda: None)


def test_kill_9_during_training_never_loses_a_checkpoint(tmp_path):
    rng = np.random.default_rng(9)
    out = tmp_path / "ckpt"
    resume = resume_dir_for(out)

    def cmd(steps: int) -> list[str]:
        return [sys.executable, "-m", "paper_lib.agents.training", "CartPole-v1", "ensemble", "0", str(out),
                "--timesteps", str(steps), "--resume-every", "128"]

    budget = 256
    cpu = finish(cmd(budget), tmp_path)
    in_place = assert_complete_checkpoint(out)["trained_timesteps"]
    assert in_place == budget
    budgets = [budget]

    def start_run(at_cpu: float) -> bool:
        budgets.append(budgets[-1] + 256)  # every run has steps to train and a new checkpoint to swap in
        return run_and_kill(cmd(budgets[-1]), tmp_path, at_cpu, out.is_dir)

    def check() -> None:
        nonlocal in_place
        config = assert_complete_checkpoint(out)  # the old one or the new one, whole
        assert config["trained_timesteps"] in (in_place, budgets[-1])
        in_place = config["trained_timesteps"]
        assert_complete_resume_point(resume)

    assert kill_until(2, rng, cpu, start_run, check) == 2
    budget = budgets[-1]
    finish(cmd(budget), tmp_path)
    config = assert_complete_checkpoint(out)
    assert config["trained_timesteps"] == budget
    PPO.load(out / "model.zip", device="cpu")
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == [".ckpt.resume", "ckpt"], f"temporary folders of killed runs remain: {left}"


# ----------------------------------------------------------------------------- collection


def tiny_params(tmp_path: Path) -> Path:
    """The tiny profile, one run (HalfCheetah baseline), with its results under tmp_path."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["run"] = {"profile": "tiny", **params["profiles"]["tiny"], "methods": ["baseline"]}
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


#: `python -m paper_lib.pipeline.stages ARGS`, except that the dataset's bytes are written in two halves one
#: second apart: a kill can then be aimed into the write itself, which otherwise lasts milliseconds.
SLOW_WRITE = r"""
import io, runpy, sys, time
import numpy as np
import pytest
savez = np.savez_compressed
def savez_in_two_halves(file, *args, **kwargs):
    buffer = io.BytesIO()
    savez(buffer, *args, **kwargs)
    data = buffer.getvalue()
    file.write(data[: len(data) // 2])
    file.flush()
    time.sleep(1.0)
    file.write(data[len(data) // 2:])
np.savez_compressed = savez_in_two_halves
sys.argv = ["paper_lib.pipeline.stages", *sys.argv[1:]]
runpy.run_module("paper_lib.pipeline.stages", run_name="__main__", alter_sys=True)
"""


def kill_while_writing(cmd: list[str], cwd: Path, target: Path, delay: float, still_there) -> None:
    """Start `cmd`; SIGKILL it `delay` seconds after the first bytes of `target`'s new copy are written.

    The kill is timed from the bytes themselves (the temp copy inside `.<name>.<random>.tmp/` growing past empty),
    not from any change in the folder: the writer's temp folder, its lock marker and any other file the run writes
    beside it appear before the first byte, and a kill timed from them could land before the write began.
    """
    def first_bytes_written() -> bool:
        try:
            return any(entry.name.startswith(f".{target.name}.") and entry.name.endswith(".tmp")
                       and (entry / target.name).is_file() and (entry / target.name).stat().st_size > 0
                       for entry in target.parent.iterdir())
        except FileNotFoundError:  # the temp was moved or swept between listing and stat
            return False

    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        while proc.poll() is None:
            assert still_there(), "the complete artifact vanished while the run was going"
            if first_bytes_written():
                time.sleep(delay)
                proc.send_signal(signal.SIGKILL)
                proc.wait()
                return
            time.sleep(0.002)
        raise AssertionError(f"the run ended without being killed: {proc.stderr.read().decode()[-3000:]}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()


def test_kill_9_during_collection_never_loses_a_dataset(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo's log
    rng = np.random.default_rng(10)
    params = tiny_params(tmp_path)
    cfg = load_run_config(params)
    train_stage(cfg, "HalfCheetah-v5", "baseline", 0)
    dataset = cfg.dataset_path("HalfCheetah-v5", "baseline", 0)
    cmd = [sys.executable, "-m", "paper_lib.pipeline.stages", "--params", str(params), "collect", "HalfCheetah-v5", "baseline", "0"]

    cpu = finish(cmd, tmp_path)
    first = StateDataset.load(dataset)

    def check() -> None:
        again = StateDataset.load(dataset)  # complete and readable: never a half-written file at the path
        np.testing.assert_array_equal(again.states, first.states)

    assert kill_until(1, rng, cpu, lambda at_cpu: run_and_kill(cmd, tmp_path, at_cpu, dataset.is_file), check) == 1
    # and a kill in the middle of writing the new dataset's bytes
    slow = [sys.executable, "-c", SLOW_WRITE, *cmd[3:]]
    kill_while_writing(slow, tmp_path, dataset, float(rng.uniform(0.0, 0.5)), dataset.is_file)
    np.testing.assert_array_equal(StateDataset.load(dataset).states, first.states)
    # the killed holder's run lock stays beside it (released by the kernel) until the next collection takes and removes it
    beside = [p.name for p in dataset.parent.iterdir() if p != dataset and p.name != f".{dataset.name}.lock"]
    assert len(beside) == 1 and beside[0].startswith(f".{dataset.name}."), "the kill landed inside the write"
    finish(cmd, tmp_path)
    np.testing.assert_array_equal(StateDataset.load(dataset).states, first.states)
    left = sorted(p.name for p in dataset.parent.iterdir())
    assert left == [dataset.name], f"temporary files of killed runs remain: {left}"


# ---------------------------------------------------------------- a killed file writer's temp (issue 71, item 4)

HOLD_OPEN = """
import sys, time
from paper_lib.common.io import atomic_path
with atomic_path(sys.argv[1]) as tmp:
    tmp.write_text("half of a figure")
    print("writing", flush=True)
    time.sleep(60)
"""


def _writer(target: Path) -> subprocess.Popen:
    """A real process inside `atomic_path(target)`, once it says so."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD_OPEN, str(target)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    return proc


def _temps(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_the_next_write_sweeps_a_killed_writers_temp_and_never_a_live_ones(tmp_path):
    """kill -9 inside a write leaves `.<name>.<random>.tmp/`; writing the file again removes it (git status stays
    clean after a killed `make reproduce` is run again), while a writer still alive keeps its temp."""
    from paper_lib.common.io import write_text_atomic

    target = tmp_path / "roc_value_policy.png"
    killed = _writer(target)
    os.kill(killed.pid, signal.SIGKILL)
    killed.wait()
    left = _temps(tmp_path)
    assert len(left) == 1 and not target.exists()
    alive = _writer(target)
    try:
        write_text_atomic(target, "the figure")
        assert target.read_text() == "the figure"
        remaining = _temps(tmp_path)
        assert left[0] not in remaining, "the killed writer's temp was left"
        assert len(remaining) == 1, "the live writer's temp must stay"
    finally:
        alive.kill()
        alive.wait()
    write_text_atomic(target, "again")
    assert _temps(tmp_path) == []


# ----------------------------------------------------------------------------- kills at any instruction


def _kill_writers_at_random_instants(write, rounds: int, seed: int) -> None:
    """Fork a child that calls `write()` in a loop, SIGKILL it after a seeded random delay; `rounds` times."""
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    write()
    one_write = time.perf_counter() - start
    for _ in range(rounds):
        pid = os.fork()
        if pid == 0:  # the child writes until it is killed, wherever in the write that lands
            try:
                while True:
                    write()
            finally:
                os._exit(1)
        time.sleep(float(rng.uniform(0.0, 3.0 * one_write)))
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)


@pytest.mark.parametrize("writer", ["atomic_dir", "write_text_atomic"])
def test_a_kill_at_any_instant_leaves_the_target_whole_and_nothing_the_next_write_keeps(tmp_path, writer):
    """SIGKILL anywhere inside a folder swap or a file write: the target is whole, and after the next write of the
    same path nothing else remains. A CI run once kept `..ckpt.resume.<random>.tmp`: `shutil.rmtree` had removed
    the marker of the old folder first, or the kill fell between the exchange and marking the old copy."""
    from paper_lib.common.io import atomic_dir, write_text_atomic

    target = tmp_path / ("ckpt" if writer == "atomic_dir" else "table.csv")

    def write() -> None:
        if writer == "atomic_dir":
            with atomic_dir(target) as tmp:
                for name in ("model.zip", "state.pkl", "config.json"):
                    (tmp / name).write_text(name)
        else:
            write_text_atomic(target, "a,b\n1,2\n")

    for seed in range(3):
        _kill_writers_at_random_instants(write, rounds=40, seed=seed)
        if writer == "atomic_dir":
            assert sorted(p.name for p in target.iterdir()) == ["config.json", "model.zip", "state.pkl"]
        else:
            assert target.read_text() == "a,b\n1,2\n"
        write()
        assert [p.name for p in tmp_path.iterdir()] == [target.name], "a killed writer's temp was kept"
