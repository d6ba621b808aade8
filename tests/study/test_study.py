"""The study (paper_lib.study): real tiny trials, real worker processes on SQLite and on a real PostgreSQL
server (pgserver), a worker killed with SIGKILL, and notebooks 09 and 10 through papermill at `tiny`."""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import optuna
import pandas as pd
import pytest
from optuna.trial import TrialState

from paper_lib.pipeline.layout import REPLACED
from paper_lib.study import analysis, scaling
from paper_lib.study.config import load_study_config
from paper_lib.study.objective import Objective, run_configuration
from paper_lib.study.recipe import other_recipe_studies
from paper_lib.study.space import agent_kwargs, parse_param
from paper_lib.study.storage import check_url, local_postgres, open_storage
from paper_lib.study.worker import (StopStudy, land_study, open_study, replace_other_recipe, run_study,
                                   run_worker)
from paper_lib.study.worker import main as worker_main

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
STUDY = "ppo-HalfCheetah-v5-baseline"  # the cheapest tiny study: workers' tests use it
optuna.logging.set_verbosity(optuna.logging.WARNING)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """A folder with the repository's params.yaml: results of the tests go under it, never into results/."""
    folder = tmp_path_factory.mktemp("study")
    shutil.copy2(REPO / "params.yaml", folder / "params.yaml")
    return folder


@pytest.fixture(scope="module")
def cfg(root):
    return load_study_config(root / "params.yaml", "tiny")


def _worker(root: Path, log: Path, *args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "paper_lib.study.worker", "--params", str(root / "params.yaml"), "--profile", "tiny",
           *args]
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg"}
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=open(log, "w"), stderr=subprocess.STDOUT)


def _wait(procs: list[subprocess.Popen], logs: list[Path], timeout: float = 300) -> None:
    for proc, log in zip(procs, logs):
        try:
            assert proc.wait(timeout=timeout) == 0, log.read_text()[-3000:]
        finally:
            proc.kill()


def _trials(url: str, name: str = STUDY) -> list[optuna.trial.FrozenTrial]:
    return optuna.load_study(study_name=name, storage=url).get_trials()


def _assert_exactly(trials: list[optuna.trial.FrozenTrial], n: int) -> list[optuna.trial.FrozenTrial]:
    """n COMPLETE trials, none left running or queued, none run twice (distinct seeds), every one recorded."""
    done = [t for t in trials if t.state == TrialState.COMPLETE]
    assert len(done) == n, [(t.number, t.state.name, t.user_attrs.get("fail_reason")) for t in trials]
    assert not [t for t in trials if t.state in (TrialState.RUNNING, TrialState.WAITING)]
    seeds = [t.user_attrs["seed"] for t in done]
    assert len(set(seeds)) == n, seeds
    for t in done:
        assert np.isfinite(t.values).all() and 0.0 <= t.values[1] <= 1.0
        assert {"seed", "config", "worker", "auroc_mahalanobis_features"} <= set(t.user_attrs)
        assert set(t.params) == set(load_study_config(REPO / "params.yaml", "tiny").study(STUDY).space)
    return done


def _two_workers(root: Path, url: str, tag: str, n: int = 3) -> None:
    logs = [root / f"{tag}-{i}.log" for i in range(2)]
    procs = [_worker(root, log, "--study", STUDY, "--storage", url, "--trials", str(n), "--sampler-seed", str(i))
             for i, log in enumerate(logs)]
    _wait(procs, logs)
    done = _assert_exactly(_trials(url), n)
    workers = {t.user_attrs["worker"] for t in done}
    assert len(workers) == 2, f"both workers should have finished trials: {workers}"
    surplus = [t for t in _trials(url) if t.state == TrialState.PRUNED]
    assert all(t.user_attrs.get("surplus") for t in surplus), "a PRUNED trial is only ever a surplus slot"


# ------------------------------------------------------------------------------------------ data and inputs


def test_search_space_and_budgets_are_checked_where_they_enter(root, tmp_path):
    with pytest.raises(ValueError, match="learning_rate.*low=0.1 must be below high=0.01"):
        parse_param("learning_rate", {"low": 0.1, "high": 0.01}, "study.space.ppo.learning_rate")
    with pytest.raises(ValueError, match="YAML reads 1e-5 without a dot"):
        parse_param("learning_rate", {"low": "1e-5", "high": 0.01}, "x")
    text = (root / "params.yaml").read_text()
    bad = tmp_path / "params.yaml"
    bad.write_text(text.replace("    a2c:\n      learning_rate:", "    a2c:\n      clip_range:\n        choices: [0.1, 0.2]\n"
                                "      learning_rate:", 1))
    with pytest.raises(ValueError, match="A2C does not take 'clip_range'"):
        load_study_config(bad, "tiny")
    with pytest.raises(ValueError, match="has no profile 'huge'"):
        load_study_config(root / "params.yaml", "huge")
    # the committed profile borrows the CPU budget (and says so); a mapping to a missing budget is one error
    paper = load_study_config(root / "params.yaml", "paper")
    assert (paper.budget, paper.studies_dir) == ("cpu", root / "results" / "paper" / "studies")
    assert paper.studies == load_study_config(root / "params.yaml", "cpu").studies
    assert "profile 'paper' at the 'cpu' study budget" in paper.budget_caption()
    assert scaling.load_scaling_config(root / "params.yaml", "paper").budget == "cpu"
    bad.write_text(text.replace("budget_of_profile: {paper: cpu}", "budget_of_profile: {paper: laptop}", 1))
    with pytest.raises(ValueError, match="maps profile 'paper' to 'laptop'"):
        load_study_config(bad, "paper")
    with pytest.raises(ValueError, match="journal files keep no heartbeats"):
        check_url("results/studies.journal")
    with pytest.raises(ValueError, match="in-memory database is lost"):
        check_url("sqlite:///:memory:")
    with pytest.raises(SystemExit) as stop:
        worker_main(["--study", "ppo-Nowhere-v5-baseline", "--params", str(root / "params.yaml"), "--profile", "tiny"])
    assert stop.value.code == 2


def test_sampled_settings_reach_make_agent(cfg):
    from paper_lib.agents.factory import make_agent

    spec = cfg.study("ppo-HalfCheetah-v5-masksembles")
    params = {"width": 64, "activation_fn": "tanh", "n_members": 2, "masksembles_scale": 3.0, "learning_rate": 1e-4,
              "clip_range": 0.3}
    kwargs = agent_kwargs(params, spec.fixed, cfg.hyperparameters["HalfCheetah-v5"])
    model = make_agent("ppo", "masksembles", "HalfCheetah-v5", 0, **kwargs)
    config = model.paper_lib_config
    assert config["hidden_sizes"] == [64, 64] and config["n_members"] == 2 and config["masksembles_scale"] == 3.0
    assert config["policy"]["activation_fn"] == "tanh"
    assert config["algo_kwargs"]["learning_rate"] == 1e-4 and config["algo_kwargs"]["clip_range"] == 0.3
    assert config["algo_kwargs"]["n_steps"] == 16  # the tiny budget's fixed setting
    model.env.close()
    # a member count the recipe's envs cannot give each its own group raises n_envs (Walker2d: 4 envs, k = 8)
    walker = cfg.hyperparameters["Walker2d-v5"]
    assert walker["n_envs"] == 4
    assert agent_kwargs({"n_members": 8}, {}, walker)["hyperparameters"]["n_envs"] == 8
    assert agent_kwargs({"n_members": 2}, {}, walker)["hyperparameters"]["n_envs"] == 4
    assert agent_kwargs({}, {}, walker)["hyperparameters"]["n_envs"] == 4 and walker["n_envs"] == 4


def test_pareto_front_and_hypervolume():
    points = np.array([[1.0, 1.0], [2.0, 0.5], [0.5, 0.5], [2.0, 1.0], [0.0, 3.0]])
    assert analysis.pareto_mask(points).tolist() == [False, False, False, True, True]
    assert analysis.hypervolume_2d(np.array([[1.0, 2.0], [2.0, 1.0]]), (0.0, 0.0)) == pytest.approx(3.0)
    assert analysis.hypervolume_2d(np.array([[1.0, 0.4]]), (0.0, 0.5)) == 0.0


def test_summary_shows_a_reward_objective_that_hardly_separates():
    # Ant at a short budget: one configuration falls over, the others stand still for ~1000 (the healthy bonus)
    trials = pd.DataFrame({"algo": "ppo", "env": "Ant-v5", "method": ["baseline"] * 4 + ["masksembles"] * 2,
                           "state": ["COMPLETE"] * 5 + ["FAIL"], "retried_from": np.nan,
                           "reward": [-2000.0, 990.0, 1000.0, 995.0, 998.0, np.nan],
                           "auroc": [0.9, 0.8, 0.7, 0.95, 0.6, np.nan]})
    summary = analysis.study_summary(trials, 0.5, 0.75).set_index("method")
    assert summary.loc["baseline", "median_reward"] == pytest.approx(992.5)
    assert summary.loc["baseline", "median_reward_norm"] == pytest.approx(2992.5 / 3000)
    assert summary.loc["masksembles", ["complete", "failed", "median_reward"]].tolist() == [1, 1, 998.0]


def test_reading_names_the_leader_overall_and_among_member_methods():
    # HalfCheetah as the first sweep read it: the baseline's member-free detector leads, Masksembles leads the members
    summary = pd.DataFrame({"algo": "ppo", "env": "HalfCheetah-v5",
                            "method": ["baseline", "masksembles", "ensemble", "mc_dropout"],
                            "performant": [5, 4, 1, 4], "hypervolume": [0.50, 0.25, 0.27, 0.10]})
    (row,) = analysis.reading(summary).to_dict("records")
    assert (row["most_performant"], row["performant"], row["largest_hypervolume"]) == ("baseline", 5, "baseline")
    assert (row["most_performant_members"], row["performant_members"]) == ("masksembles, mc_dropout", 4)
    assert (row["largest_hypervolume_members"], row["hypervolume_members"]) == ("ensemble", 0.27)


def test_other_algorithms_are_read_against_appendix_c():
    summary = pd.DataFrame({"algo": ["trpo"] * 3 + ["a2c"] * 3 + ["ppo"],
                            "env": "HalfCheetah-v5",
                            "method": ["baseline", "masksembles", "ensemble"] * 2 + ["baseline"],
                            "best_reward": [2676.0, 443.0, 429.0, 900.0, 1500.0, 300.0, 5000.0],
                            "hypervolume": [0.5, 0.02, 0.03, 0.4, 0.1, 0.2, 0.5]})
    progress = pd.DataFrame({"algo": ["trpo", "a2c"], "env": "HalfCheetah-v5", "status": [analysis.DONE, "running"]})
    table = analysis.other_algorithms_vs_paper(summary)
    assert table[["algo", "best_member", "largest_hypervolume_member", "agrees_behind_baseline",
                  "agrees_masksembles_leads"]].values.tolist() == [
        ["a2c", "masksembles", "ensemble", False, True], ["trpo", "masksembles", "ensemble", True, True]]
    assert analysis.other_algorithms_vs_paper(summary, progress)["algo"].tolist() == ["trpo"]  # A2C not done


# ------------------------------------------------------------------------------------------ trials and workers


def test_scaling_is_read_against_appendix_e():
    runs = [("Walker2d-v5", "masksembles", 64, 300.0), ("Walker2d-v5", "masksembles", 128, 330.0),  # +10%: up
            ("Walker2d-v5", "baseline", 64, 350.0), ("Walker2d-v5", "baseline", 128, 360.0),  # +2.9%: flat
            ("Walker2d-v5", "mc_dropout", 64, 400.0), ("Walker2d-v5", "mc_dropout", 128, 360.0),  # -10%: down
            ("HalfCheetah-v5", "baseline", 64, 1000.0), ("HalfCheetah-v5", "baseline", 128, 2000.0),  # not in appendix E
            ("Ant-v5", "masksembles", 64, 900.0)]  # its 128 run not trained: not read
    table = pd.DataFrame(runs, columns=["env", "method", "width", "mean"])
    status = table[["env", "method", "width"]].assign(status=scaling.TRAINED)
    status = pd.concat([status, pd.DataFrame([{"env": "Ant-v5", "method": "masksembles", "width": 128,
                                               "status": scaling.NOT_TRAINED}])], ignore_index=True)
    versus = scaling.paper_comparison(scaling.width_reading(table, status), table)
    assert versus[["method", "ours", "agrees"]].values.tolist() == [
        ["masksembles", "up", True], ["baseline", "flat", True], ["mc_dropout", "down", False]]
    assert versus["relative_change"].round(3).tolist() == [0.1, 0.029, -0.1]


def test_a_failing_trial_is_recorded_with_its_reason_and_the_study_goes_on(cfg, tmp_path):
    """Learning rate 1e4 makes the policy's action distribution NaN: that trial fails with its reason, the next runs."""
    spec = cfg.study("ppo-HalfCheetah-v5-masksembles")
    storage = open_storage(f"sqlite:///{tmp_path / 'fail.db'}", cfg.heartbeat)
    study = open_study(cfg, spec, storage, sampler_seed=0)
    study.enqueue_trial({"learning_rate": 1e4, "n_members": 2})
    study.enqueue_trial({"learning_rate": 3e-4, "n_members": 2})
    lines: list[str] = []
    with pytest.warns(UserWarning, match="out of range"):  # Optuna says so of the enqueued 1e4, and uses it
        run_worker(study, Objective(cfg, spec), n_trials=1, log=lines.append)
    failed, done = study.trials
    assert failed.state == TrialState.FAIL and done.state == TrialState.COMPLETE, lines
    assert "ValueError" in failed.user_attrs["fail_reason"] and "seed" in failed.user_attrs
    assert "FAIL" in lines[0] and "COMPLETE" in lines[1]
    # the record is enough to repeat the trial: its settings and seed give the same two numbers
    again = run_configuration(cfg, spec, done.params, done.user_attrs["seed"], tmp_path)
    assert (again.reward, again.auroc) == pytest.approx(tuple(done.values), abs=0, rel=0)
    # a study whose every trial fails stops with the reason instead of looping
    study.enqueue_trial({"learning_rate": 1e4, "n_members": 2})
    with pytest.raises(StopStudy, match="ValueError"), pytest.warns(UserWarning, match="out of range"):
        run_worker(study, Objective(cfg, spec), n_trials=2, max_failures=2)


def test_two_worker_processes_share_a_sqlite_study(root):
    _two_workers(root, f"sqlite:///{root / 'two.db'}", "sqlite")


def _until_training(root: Path, worker: subprocess.Popen, log: Path, url: str) -> None:
    """Wait until trial 0 has drawn its settings and is training."""
    n_params = len(load_study_config(root / "params.yaml", "tiny").study(STUDY).space)
    deadline = time.monotonic() + 240
    while True:
        assert worker.poll() is None and time.monotonic() < deadline, log.read_text()[-3000:]
        try:
            running = [t for t in _trials(url) if t.state == TrialState.RUNNING and len(t.params) == n_params]
        except Exception:  # the database or the study is not there yet
            running = []
        if running:
            return
        time.sleep(0.2)


def test_a_worker_stopped_by_sigterm_queues_its_trial_again_at_once(root):
    """What a lease's `timeout -s TERM` relies on: the cut trial is FAIL, and a WAITING copy has its settings."""
    url = f"sqlite:///{root / 'term.db'}"
    worker = _worker(root, root / "term.log", "--study", STUDY, "--storage", url, "--trials", "2")
    try:
        _until_training(root, worker, root / "term.log", url)
        worker.send_signal(signal.SIGTERM)
        assert worker.wait(timeout=60) == 130, (root / "term.log").read_text()[-3000:]
    finally:
        worker.kill()
    cut, *rest = _trials(url)
    assert cut.state == TrialState.FAIL and "fail_reason" not in cut.user_attrs
    assert [(t.state, t.params, t.system_attrs.get("failed_trial")) for t in rest] == [(TrialState.WAITING, cut.params, 0)]


def test_sigterm_during_a_string_exec_still_exits_with_130(tmp_path):
    """CPython kills a `python -m` process by SIGINT at exit if a bare KeyboardInterrupt left a string exec,
    caught or not; the worker's SIGTERM exception must not do that (a CI run caught it there once)."""
    (tmp_path / "stop_in_exec.py").write_text(
        "import os, signal, sys\n"
        "from paper_lib.study.worker import _interrupt\n"
        "signal.signal(signal.SIGTERM, _interrupt)\n"
        "try:\n"
        "    exec('import os, signal, time\\nos.kill(os.getpid(), signal.SIGTERM)\\ntime.sleep(5)')\n"
        "except KeyboardInterrupt:\n"
        "    sys.exit(130)\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-m", "stop_in_exec"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 130, done.stderr


def test_a_worker_killed_mid_trial_leaves_a_failed_trial_that_is_retried(root):
    url = f"sqlite:///{root / 'kill.db'}"
    first = _worker(root, root / "kill-0.log", "--study", STUDY, "--storage", url, "--trials", "2")
    try:
        _until_training(root, first, root / "kill-0.log", url)
        os.kill(first.pid, signal.SIGKILL)
        first.wait(timeout=30)
    finally:
        first.kill()
    killed = _trials(url)[0]
    assert killed.state == TrialState.RUNNING  # as the dead worker left it
    second = _worker(root, root / "kill-1.log", "--study", STUDY, "--storage", url, "--trials", "2")
    _wait([second], [root / "kill-1.log"])
    trials = _trials(url)
    done = _assert_exactly(trials, 2)
    assert trials[0].state == TrialState.FAIL and "fail_reason" not in trials[0].user_attrs
    retry = [t for t in done if t.system_attrs.get("failed_trial") == 0]
    assert len(retry) == 1, [(t.number, t.state.name, t.system_attrs) for t in trials]
    assert retry[0].params == killed.params and retry[0].user_attrs["seed"] == killed.user_attrs["seed"]


def test_two_worker_processes_share_a_study_on_a_real_postgresql_server(root):
    # not under pytest's tmp folder: other pytest sessions reset its parent to 0700, which the server's user
    # (`pgserver`, when tests run as root) could then not enter
    data = Path(tempfile.mkdtemp(prefix="paper_lib-test-pg-")) / "data"
    try:
        server, url = local_postgres(data, cleanup="delete")
    except Exception as err:  # no skip: without a server this test has not shown anything
        pytest.fail(f"PostgreSQL (pgserver, pinned in environment.lock) did not start: {err}")
    try:
        assert url.startswith("postgresql://")
        _two_workers(root, url, "postgres")
    finally:
        server.cleanup()
        shutil.rmtree(data.parent, ignore_errors=True)


# ------------------------------------------------------------------------------------------ notebooks


def _papermill(notebook: str, out: Path, root: Path) -> None:
    """The notebook through the project's papermill runner, as its DVC stage runs it."""
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg"}
    done = subprocess.run([str(BIN / "python"), "-m", "paper_lib.pipeline.notebook_run", f"notebooks/{notebook}",
                           str(out), "-p", "params_file", str(root / "params.yaml"), "-p", "profile", "tiny"],
                          cwd=REPO, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]


def test_study_and_scaling_notebooks_run_at_tiny(root, cfg):
    # first mid-sweep, as `make reproduce` finds a sweep of hours: one study done, the others not begun
    run_study(cfg, STUDY, sampler_seed=0, log=lambda line: None)
    _papermill("09_study.ipynb", root / "09_partial.ipynb", root)
    results = root / "results" / "tiny"
    progress = pd.read_csv(results / "tables" / "study" / "study_progress.csv").set_index("study")
    assert progress.loc[STUDY, "status"] == "done" and progress.loc[STUDY, "complete"] == 2
    assert (progress.drop(STUDY)["status"] == "not started").all() and len(progress) == len(cfg.studies)
    verdict = pd.read_csv(results / "tables" / "study" / "study_reading.csv")
    assert (verdict["largest_hypervolume"] == analysis.NOT_READ).all(), "no env is read before all its studies ran"
    assert "1 of 4 studies at their trial target" in (results / "tables" / "study" / "study_summary.md").read_text()

    for name in cfg.studies:  # every tiny study to its target, in this process (the sweep's DVC stage)
        run_study(cfg, name, sampler_seed=0, log=lambda line: None)
    _papermill("09_study.ipynb", root / "09.ipynb", root)
    verdict = pd.read_csv(results / "tables" / "study" / "study_reading.csv")
    assert verdict["largest_hypervolume"].isin({"baseline", "masksembles"}).all()  # every env read: tiny's methods
    assert (verdict["largest_hypervolume_members"] == "masksembles").all()  # tiny's only member method
    trials = pd.read_csv(results / "tables" / "study" / "study_trials.csv")
    assert set(trials["study"]) == set(cfg.studies)
    assert (trials.groupby("study")["state"].apply(lambda s: (s == "COMPLETE").sum()) == 2).all()
    summary = pd.read_csv(results / "tables" / "study" / "study_summary.csv")
    assert len(summary) == len(cfg.studies) and summary["front_size"].ge(1).all()
    for stem in ("study_scatter_mujoco", "study_scatter_other_algs", "study_ablation_n_members_auroc",
                 "study_ablation_n_members_reward_norm"):
        assert (results / "figures" / "study" / f"{stem}.png").stat().st_size > 0
    assert "profile 'tiny'" in (results / "tables" / "study" / "study_best_configs.md").read_text().splitlines()[0]

    scaling_cfg = scaling.load_scaling_config(root / "params.yaml", "tiny")
    # first mid-way, as `make reproduce` finds scaling runs of hours: one run trained, the others not begun
    scaling.train_missing(dataclasses.replace(scaling_cfg, runs=scaling_cfg.runs[:1]), log=lambda line: None)
    _papermill("10_scaling.ipynb", root / "10_partial.ipynb", root)
    final = pd.read_csv(results / "tables" / "scaling" / "scaling_final_reward.csv")
    assert len(final) == 1 and final["width"].tolist() == [scaling_cfg.runs[0].width]
    status = pd.read_csv(results / "tables" / "scaling" / "scaling_progress.csv")
    assert status["status"].tolist() == [scaling.TRAINED] + [scaling.NOT_TRAINED] * (len(scaling_cfg.runs) - 1)
    assert not pd.read_csv(results / "tables" / "scaling" / "scaling_reading.csv")["read"].any()
    assert pd.read_csv(results / "tables" / "scaling" / "scaling_vs_paper.csv").empty  # nothing read, nothing compared
    assert "1 of 4 scaling runs trained" in (results / "tables" / "scaling" / "scaling_final_reward.md").read_text()

    scaling.train_missing(scaling_cfg, log=lambda line: None)
    _papermill("10_scaling.ipynb", root / "10.ipynb", root)
    final = pd.read_csv(results / "tables" / "scaling" / "scaling_final_reward.csv")
    assert len(final) == len(scaling_cfg.runs) and set(final["width"]) == {64, 96}
    assert pd.read_csv(results / "tables" / "scaling" / "scaling_reading.csv")["read"].all()
    versus = pd.read_csv(results / "tables" / "scaling" / "scaling_vs_paper.csv")
    assert versus["method"].tolist() == ["baseline", "masksembles"] and set(versus["ours"]) <= {"up", "flat", "down"}
    assert (results / "figures" / "scaling" / "scaling_curves.png").stat().st_size > 0
    # The final rewards were played once, when each run landed; the notebook only read them, checked against the
    # checkpoint beside them: another run's file (here: another width's) is refused, naming the difference.
    first, second = scaling_cfg.runs[0], scaling_cfg.runs[1]
    assert scaling.read_evaluation(scaling_cfg, first) == replayed_rewards(scaling_cfg, first)  # same machine, same seed
    shutil.copy2(scaling_cfg.run_dir(first) / scaling.EVALUATION_FILE, scaling_cfg.run_dir(second) / scaling.EVALUATION_FILE)
    with pytest.raises(ValueError, match=r"does not belong to this run \(width is 64, this run's is 96; "
                                         r"checkpoint_sha256 is"):
        scaling.read_evaluation(scaling_cfg, second)

    # An env's recipe changes (issue 38's Walker2d): its scaling runs and studies of the old one are not read as
    # the new one's. The scaling runs show as "another recipe" and training moves each aside before training it
    # again; the studies are left out of notebook 9 and a worker refuses to add trials to them.
    newer = copy.deepcopy(scaling_cfg.hyperparameters)
    newer["Walker2d-v5"]["algo"]["gamma"] = 0.95
    changed = dataclasses.replace(scaling_cfg, hyperparameters=newer)
    assert scaling.progress(changed)["status"].eq(scaling.OTHER_RECIPE).all()
    assert "gamma: trained with 0.99" in "; ".join(scaling.recipe_differences(changed, first))
    scaling.train_missing(scaling.select(changed, width=first.width, method=first.method), log=lambda line: None)
    assert scaling.run_status(changed, first) == scaling.TRAINED
    assert scaling.run_status(scaling_cfg, first) == scaling.OTHER_RECIPE  # the retrained run is of the new recipe
    replaced = root / REPLACED / scaling_cfg.run_dir(first).relative_to(root)
    assert json.loads((replaced / "config.json").read_text())["algo_kwargs"]["gamma"] == 0.99  # kept, outside results/
    with pytest.raises(ValueError, match="no scaling run of budget 'tiny' has width 1000"):
        scaling.select(changed, width=1000)
    # a run trained elsewhere (a training queue's worktree) lands: copied in over the older one, then evaluated once
    second_run = scaling.select(changed, width=second.width, method=second.method)
    elsewhere = dataclasses.replace(second_run, root=root / "frozen")
    scaling.train_missing(elsewhere, log=lambda line: None)
    assert scaling.land_from(second_run, root / "frozen", log=lambda line: None) == [second]
    assert scaling.run_status(changed, second) == scaling.TRAINED and scaling.is_evaluated(changed, second)
    assert scaling.land_from(second_run, root / "frozen", log=lambda line: None) == []  # nothing left to land
    with pytest.raises(ValueError, match="has no results/ folder"):
        scaling.land_from(second_run, root / "nowhere")

    assert other_recipe_studies(cfg, cfg.default_storage_url()) == {}
    newer = copy.deepcopy(cfg.hyperparameters)
    newer["HalfCheetah-v5"]["normalize_obs"] = False
    changed = dataclasses.replace(cfg, hyperparameters=newer)
    older = other_recipe_studies(changed, changed.default_storage_url())
    assert set(older) == set(cfg.studies) and "normalize_obs: trained with True, params.yaml gives False" in older[STUDY]
    status = analysis.progress(pd.DataFrame(columns=analysis.TRIAL_COLUMNS), {STUDY: 2}, older)
    assert status["status"].tolist() == [analysis.OTHER_RECIPE]
    with pytest.raises(ValueError, match="holds trials of another recipe .*normalize_obs: trained with True"):
        run_study(changed, STUDY, sampler_seed=0, log=lambda line: None)
    kept = replace_other_recipe(changed, STUDY, log=lambda line: None)  # what --replace-other-recipe does first
    assert STUDY not in optuna.get_all_study_names(storage=cfg.default_storage_url())
    assert STUDY in optuna.get_all_study_names(storage=f"sqlite:///{kept}")  # the old trials are kept, outside results/
    assert replace_other_recipe(changed, STUDY, log=lambda line: None) is None  # nothing of another recipe left
    # a study done in another worktree's database lands here (the old one was replaced above); twice lands nothing
    elsewhere = f"sqlite:///{root / 'elsewhere.db'}"
    run_study(changed, STUDY, storage_url=elsewhere, sampler_seed=0, log=lambda line: None)
    assert land_study(changed, STUDY, elsewhere, log=lambda line: None)
    assert len(_trials(cfg.default_storage_url())) == len(_trials(elsewhere))
    assert not land_study(changed, STUDY, elsewhere, log=lambda line: None)


def replayed_rewards(cfg, run) -> list[float]:
    """The run's deterministic evaluation episodes played again here, as `evaluate_run` played them."""
    from paper_lib.agents.checkpoints import load_checkpoint
    from paper_lib.study.objective import evaluation_episodes

    checkpoint = load_checkpoint(cfg.run_dir(run), run.env_id, run.method, run.seed)
    return evaluation_episodes(checkpoint, cfg.eval_episodes, scaling.EVAL_SEED_OFFSET + run.seed, deterministic=True)
