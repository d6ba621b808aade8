"""scripts/resume_points.sh: a run longer than one machine's session survives it through the repository."""

from __future__ import annotations

import pickle
import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "resume_points.sh"
RUN = "recipe_probes/Ant-v5/baseline-zoo-n4"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True)


def _resume_point(tree: Path, seed: int, content: bytes) -> Path:
    folder = tree / "results" / RUN / f".seed{seed}.resume"
    folder.mkdir(parents=True)
    for name in ("model.zip", "state.pkl", "vecnormalize.pkl"):
        (folder / name).write_bytes(content + name.encode())
    return folder


def _checkpoint(root: Path, seed: int, content: bytes) -> None:
    """A finished run's model.zip at RUN/seed<seed> under root/results."""
    folder = root / "results" / RUN / f"seed{seed}"
    folder.mkdir(parents=True)
    (folder / "model.zip").write_bytes(content)


def test_save_then_restore_on_another_machine(tmp_path):
    old_machine, repo, new_machine = tmp_path / "frozen", tmp_path / "repo", tmp_path / "next"
    for root in (old_machine, repo, new_machine):
        (root / "results").mkdir(parents=True)
    _resume_point(old_machine, 0, b"in progress")
    _resume_point(old_machine, 1, b"finished")
    for root in (old_machine, repo):
        _checkpoint(root, 1, b"checkpoint")  # seed 1 has landed: nothing to carry
    stale = repo / "results" / "resume_points" / RUN / "seed1"
    stale.mkdir(parents=True)
    (stale / "state.pkl").write_bytes(b"old")

    saved = _run("save", str(old_machine), str(repo))
    assert saved.returncode == 0, saved.stderr
    store = repo / "results" / "resume_points" / RUN
    assert sorted(p.name for p in (store / "seed0").iterdir()) == ["model.zip", "state.pkl", "vecnormalize.pkl"]
    assert (store / "seed0" / "state.pkl").read_bytes() == b"in progressstate.pkl"
    assert not stale.exists()  # the landed run's copy is dropped

    restored = _run("restore", str(repo), str(new_machine))
    assert restored.returncode == 0, restored.stderr
    back = new_machine / "results" / RUN / ".seed0.resume"
    assert (back / "model.zip").read_bytes() == b"in progressmodel.zip"


def test_a_finished_run_not_landed_yet_keeps_its_resume_point(tmp_path):
    """Finished in the training tree, but the repository still holds the run it replaces (or none): its last resume
    point is what lands it on another machine, so it is carried."""
    tree, repo = tmp_path / "frozen", tmp_path / "repo"
    _resume_point(tree, 1, b"finished")
    _checkpoint(tree, 1, b"new checkpoint")
    _checkpoint(repo, 1, b"the old recipe's checkpoint")
    assert _run("save", str(tree), str(repo)).returncode == 0
    assert (repo / "results" / "resume_points" / RUN / "seed1" / "state.pkl").read_bytes() == b"finishedstate.pkl"


def test_a_run_retrained_in_place_keeps_its_resume_point(tmp_path):
    """The training tree still holds the older run (the repository's, byte for byte) that the run in progress will
    replace: that is not a landing, and dropping the resume point would throw away hours of training."""
    tree, repo = tmp_path / "frozen", tmp_path / "repo"
    point = _resume_point(tree, 1, b"in progress")
    _state(point, 2_000_000, 3600.0)
    for root in (tree, repo):
        _checkpoint(root, 1, b"the old recipe's checkpoint")
        (root / "results" / RUN / "seed1" / "config.json").write_text('{"trained_timesteps": 1000000}')
    assert _run("save", str(tree), str(repo)).returncode == 0
    saved = repo / "results" / "resume_points" / RUN / "seed1" / "state.pkl"
    assert pickle.loads(saved.read_bytes())["num_timesteps"] == 2_000_000
    _state(point, 1_000_000, 1800.0)  # had it been this checkpoint's own resume point, it would have landed
    assert _run("save", str(tree), str(repo)).returncode == 0 and not saved.exists()


def test_keep_landed_carries_a_finished_run_to_extend_later(tmp_path):
    tree, repo = tmp_path / "frozen", tmp_path / "repo"
    _resume_point(tree, 1, b"finished")
    for root in (tree, repo):
        _checkpoint(root, 1, b"checkpoint")
    assert _run("save", str(tree), str(repo)).returncode == 0
    assert not (repo / "results" / "resume_points" / RUN / "seed1").exists()
    assert _run("save", "--keep-landed", str(tree), str(repo)).returncode == 0
    assert (repo / "results" / "resume_points" / RUN / "seed1" / "state.pkl").read_bytes() == b"finishedstate.pkl"


def _state(folder: Path, step: int, wall_seconds: float) -> bytes:
    data = pickle.dumps({"num_timesteps": step, "wall_seconds": wall_seconds})
    (folder / "state.pkl").write_bytes(data)
    return data


def test_a_resume_point_at_the_saved_step_keeps_the_saved_bytes(tmp_path):
    """A finished run landing again on a new machine rewrites its resume point without training: not a change."""
    tree, repo = tmp_path / "frozen", tmp_path / "repo"
    (repo / "results").mkdir(parents=True)
    point = _resume_point(tree, 0, b"at 1e6")
    first = _state(point, 1_000_000, 4279.56)
    assert _run("save", str(tree), str(repo)).returncode == 0
    store = repo / "results" / "resume_points" / RUN / "seed0"
    assert (store / "state.pkl").read_bytes() == first

    _state(point, 1_000_000, 4279.57)  # landed again: same step, a few ms more wall time, a new zip
    (point / "model.zip").write_bytes(b"same weights, new zip timestamps")
    done = _run("save", str(tree), str(repo))
    assert done.returncode == 0 and "kept" in done.stdout, done.stdout + done.stderr
    assert (store / "state.pkl").read_bytes() == first and (store / "model.zip").read_bytes() == b"at 1e6model.zip"

    later = _state(point, 1_200_000, 5000.0)  # trained on: saved
    assert _run("save", str(tree), str(repo)).returncode == 0
    assert (store / "state.pkl").read_bytes() == later
    assert (store / "model.zip").read_bytes() == b"same weights, new zip timestamps"


def test_a_tree_without_results_is_one_clear_error(tmp_path):
    done = _run("save", str(tmp_path), str(tmp_path))
    assert done.returncode == 2 and "has no results/ folder" in done.stderr
    assert _run("bogus").returncode == 2


def _study_db(path: Path, name: str, *xs: float) -> str:
    """An Optuna SQLite database at path with one two-objective study holding a COMPLETE trial per x."""
    import optuna
    from optuna.distributions import FloatDistribution

    path.parent.mkdir(parents=True, exist_ok=True)
    url = f"sqlite:///{path}"
    study = optuna.create_study(study_name=name, storage=url, directions=["maximize", "maximize"], load_if_exists=True)
    for x in xs:
        study.add_trial(optuna.trial.create_trial(params={"x": x}, distributions={"x": FloatDistribution(0, 1)},
                                                  values=[x, 1 - x]))
    return url


def test_studies_in_progress_travel_with_the_repository(tmp_path):
    """A study worker's trials in the training tree's database are carried until they land in the repository's."""
    import optuna

    db = Path("results/paper/studies/studies.db")
    tree, repo, new_machine = tmp_path / "frozen", tmp_path / "repo", tmp_path / "next"
    _study_db(repo / db, "ppo-Ant-v5-baseline", 0.1)          # the committed study of the older recipe
    tree_url = _study_db(tree / db, "ppo-Ant-v5-baseline", 0.3, 0.4)  # its replacement, half trained
    stored = repo / "results" / "resume_points" / db.relative_to("results")

    saved = _run("save", str(tree), str(repo))
    assert saved.returncode == 0 and "saved" in saved.stdout, saved.stdout + saved.stderr
    first = stored.read_bytes()
    again = _run("save", str(tree), str(repo))  # the same trials: the saved bytes stay
    assert "kept" in again.stdout and stored.read_bytes() == first, again.stdout + again.stderr

    (new_machine / "results").mkdir(parents=True)
    assert _run("restore", str(repo), str(new_machine)).returncode == 0
    back = optuna.load_study(study_name="ppo-Ant-v5-baseline", storage=f"sqlite:///{new_machine / db}")
    assert sorted(t.params["x"] for t in back.trials) == [0.3, 0.4]

    (repo / db).unlink()  # the finished study lands: the repository's database now holds its trials
    optuna.copy_study(from_study_name="ppo-Ant-v5-baseline", from_storage=tree_url,
                      to_storage=f"sqlite:///{repo / db}")
    landed = _run("save", str(tree), str(repo))
    assert landed.returncode == 0 and not stored.exists(), landed.stdout + landed.stderr


def test_a_finished_run_travels_as_its_checkpoint_and_is_dropped_once_landed(tmp_path):
    """A run that finished but has not landed travels as its checkpoint (no optimizer state: an Atari Ensemble's is
    14 MB, its resume point 79 MB), comes back where training finds it done, and goes once the repository holds it."""
    tree, repo, new_machine = tmp_path / "frozen", tmp_path / "repo", tmp_path / "next"
    (repo / "results").mkdir(parents=True)
    (new_machine / "results").mkdir(parents=True)
    _state(_resume_point(tree, 2, b"with optimizer"), 1_000_448, 10_000.0)
    _checkpoint(tree, 2, b"finished weights")
    (tree / "results" / RUN / "seed2" / "config.json").write_text('{"trained_timesteps": 1000448}')

    saved = _run("save", str(tree), str(repo))
    store = repo / "results" / "resume_points" / RUN / "seed2"
    assert saved.returncode == 0 and "finished checkpoint" in saved.stdout, saved.stdout + saved.stderr
    assert sorted(p.name for p in store.iterdir()) == ["config.json", "model.zip"]
    again = _run("save", str(tree), str(repo))
    assert "kept" in again.stdout and (store / "model.zip").read_bytes() == b"finished weights"

    restored = _run("restore", str(repo), str(new_machine))
    assert restored.returncode == 0, restored.stderr
    assert (new_machine / "results" / RUN / "seed2" / "model.zip").read_bytes() == b"finished weights"
    assert not (new_machine / "results" / RUN / ".seed2.resume").exists()

    _checkpoint(repo, 2, b"finished weights")  # landed from the new machine, whose tree has no resume point of it
    dropped = _run("save", str(new_machine), str(repo))
    assert dropped.returncode == 0 and "dropped" in dropped.stdout and not store.exists(), dropped.stdout
