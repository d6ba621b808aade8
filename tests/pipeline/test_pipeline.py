"""The whole DVC pipeline on the `tiny` profile, in a temporary copy of the repository.

The copy's profile asks for seeds 0 and 1 but only seed 0 is trained (the retrain path, plain
`dvc repro` of seed 0's stages), and what simulates beside the runs is played once (what `make recollect`
runs: the recordings and the experiments). The README's main command must then build every table and
figure from the runs that exist, list the others, and train, collect or play nothing: it runs with
environment construction made impossible (tests/no_env/sitecustomize.py, loaded by every Python process
it starts) and must leave the committed tree unchanged.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
#: Notebooks of the main command that draw figures, with the least number of figures each shows inline.
FIGURES_SHOWN = {"00_quickstart": 2, "03_ood_detection": 2, "04_uncertainty_over_time": 2,
                 "05_training_and_perturbations": 3, "07_example_states": 2, "08_guard": 3,
                 "12_spawn": 1, "13_value_level": 1}


def _copy_repo(dst: Path) -> Path:
    """The repository without results/ and without dvc.lock, whose entries describe results/paper/ only.

    DVC rewrites the whole lock after every stage it runs (a round-trip YAML parse and dump): with the committed
    600 kB lock that is about 9 s a stage here, a third of this module's time, spent on entries the copy has no
    files for.
    """
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, check=True,
                           capture_output=True, text=True).stdout.split()
    for rel in files:
        if rel.startswith("results/") or rel == "dvc.lock":
            continue
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, target)
    _git(dst, "init", "-q")
    return dst


def _run(args: list[str], cwd: Path, extra_env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg", "DVC_NO_ANALYTICS": "1",
           **(extra_env or {})}
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, check=False)


def _git(repo: Path, *args: str) -> str:
    done = subprocess.run(["git", "-c", "user.name=test", "-c", "user.email=test@example.com", *args], cwd=repo,
                          check=True, capture_output=True, text=True)
    return done.stdout


#: What `make recollect` plays beside the runs' collection and evaluation.
SIMULATING_STAGES = ("record_example_states", "record_quickstart", "guard", "spawn", "value_level")


def _reproduce(repo: Path) -> subprocess.CompletedProcess:
    """The main command, in a world where no environment can be built."""
    no_env = {"PYTHONPATH": str(repo / "tests" / "no_env")}
    done = _run([str(BIN / "python"), "-m", "paper_lib.pipeline.reproduce"], repo, no_env)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done


@pytest.fixture(scope="module")
def tiny_repo(tmp_path_factory) -> Path:
    repo = _copy_repo(tmp_path_factory.mktemp("repo"))
    done = _run([str(BIN / "python"), "-m", "paper_lib.pipeline.config", "use", "tiny"], repo)
    assert done.returncode == 0, done.stderr
    params = yaml.safe_load((repo / "params.yaml").read_text())
    assert params["run"]["seeds"] == [0]
    text = (repo / "params.yaml").read_text()
    (repo / "params.yaml").write_text(text.replace("  seeds: [0]\n", "  seeds: [0, 1]\n", 1))  # the `run` section
    asked = ["--add", "HalfCheetah-v5", "baseline", "0", "--add", "HalfCheetah-v5", "masksembles", "0"]
    done = _run([str(BIN / "python"), "-m", "paper_lib.pipeline.run_list", *asked], repo)  # seed 0 gets its stages
    assert done.returncode == 0, done.stderr
    seed0 = [f"{stage}@HalfCheetah-v5-{method}-0" for stage in ("evaluate", "score") for method in ("baseline", "masksembles")]
    seed0.append("common_score@HalfCheetah-v5-masksembles-0")  # scored when the runs land, as `score`
    done = _run([str(BIN / "dvc"), "repro", *seed0], repo)  # trains and collects seed 0 only
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    done = _run([str(BIN / "dvc"), "repro", "--single-item", *SIMULATING_STAGES], repo)  # as `make recollect` does
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    _git(repo, "add", "-A")
    _git(repo, "commit", "-qm", "seed 0 trained, recordings and experiments played")
    repo.joinpath("main_command.log").write_text(_reproduce(repo).stdout)
    _git(repo, "add", "-A")
    _git(repo, "commit", "-qm", "tables and figures")
    repo.joinpath("second_rebuild.log").write_text(_reproduce(repo).stdout)
    return repo


def _declared_outputs(repo: Path) -> list[Path]:
    lock = yaml.safe_load((repo / "dvc.lock").read_text())
    outs = [out["path"] for stage in lock["stages"].values() for out in stage.get("outs", [])]
    return [repo / path for path in outs if path.startswith("results/tiny/")]


def test_main_command_lists_missing_runs_and_trains_nothing(tiny_repo):
    log = (tiny_repo / "main_command.log").read_text()
    for stage in ("train@", "collect@", "evaluate@", "score@", *SIMULATING_STAGES):
        assert f"Running stage '{stage}" not in log, log
    for stage in ("rewards", "ood", "uncertainty_over_time", "training_and_perturbations", "paper_vs_us",
                  "example_states", "quickstart"):
        assert f"Running stage '{stage}'" in log, log
    assert "Running stage 'sequence_score@HalfCheetah-v5-masksembles-0'" in log, log  # it reads the dataset only
    for stage in ("study", "scaling", "ensembles", "pedm_protocol"):  # their inputs are made by long runs only
        assert f"{stage}: skipped" in log and f"Running stage '{stage}'" not in log, log
    assert "Running stage 'ensembles_scores'" not in log, log
    assert "missing (not made here): HalfCheetah-v5 masksembles seed 1: no checkpoint" in log
    assert not (tiny_repo / "results/tiny/checkpoints/HalfCheetah-v5/masksembles/seed1").exists()
    runs = (tiny_repo / "results/tiny/runs.md").read_text()
    assert "4 runs, 2 complete" in runs and "HalfCheetah-v5 baseline seed 1: no checkpoint" in runs
    assert "Training wall time of the 2 runs trained on the CPU: " in runs  # summed from the runs' config.json


def test_dvc_repro_plans_no_training_collection_or_evaluation_on_the_committed_tree(tiny_repo):
    """Per-run stages exist for the runs with a committed checkpoint only (runs.yaml), so seed 1 is not trained."""
    listed = yaml.safe_load((tiny_repo / "runs.yaml").read_text())
    assert listed["profile"] == "tiny" and sorted(listed["committed_runs"]) == [
        "HalfCheetah-v5-baseline-0", "HalfCheetah-v5-masksembles-0"]
    done = _run([str(BIN / "dvc"), "stage", "list", "--name-only"], tiny_repo)
    per_run = [name for name in done.stdout.split() if "@" in name]
    # 4 stages per run, each MuJoCo run's sequence_score, and the member run's common_score (the baseline's states)
    assert done.returncode == 0 and len(per_run) == 11 and not any(name.endswith("-1") for name in per_run), done.stdout
    assert "common_score@HalfCheetah-v5-masksembles-0" in per_run, done.stdout
    assert {"sequence_score@HalfCheetah-v5-baseline-0", "sequence_score@HalfCheetah-v5-masksembles-0"} <= set(per_run)
    # nothing of them is planned: `dvc status` (what `dvc repro` acts on) finds every per-run stage up to date (the
    # tiny copy has no study database, so `dvc repro --dry` would stop at the study stages, which long runs feed)
    done = _run([str(BIN / "dvc"), "status", "--json"], tiny_repo)
    changed = json.loads(done.stdout)
    assert done.returncode == 0 and not [name for name in changed if "@" in name], changed


def test_every_table_and_figure_from_the_runs_that_exist(tiny_repo):
    results = tiny_repo / "results" / "tiny"
    outputs = _declared_outputs(tiny_repo)
    assert len(outputs) > 30
    for out in outputs:
        assert out.exists(), out
        files = [out] if out.is_file() else [p for p in out.rglob("*") if p.is_file()]
        assert files, f"{out} is empty"
        assert all(f.stat().st_size > 0 for f in files), out
    for stem in ("rewards", "ood_auroc_perturbed", "ood_auroc_noise", "ood_metrics", "paper_vs_us_rewards",
                 "paper_vs_us_auroc", "perturbation_ratios", "spawn_uncertainty", "value_level", "paper_claims"):
        for suffix in (".csv", ".md", ".tex"):
            assert (results / "tables" / f"{stem}{suffix}").stat().st_size > 0
    for stem in ("training_curves", "roc_value_policy", "roc_policy_js"):
        for suffix in (".png", ".pdf"):
            assert (results / "figures" / f"{stem}{suffix}").stat().st_size > 0
    for folder in ("over_time", "perturbation_bars", "example_states", "quickstart", "guard", "spawn", "value_level"):
        assert list((results / "figures" / folder).glob("*.png")), folder
    caption = (results / "tables" / "rewards.md").read_text().splitlines()[0]
    assert "profile 'tiny': 2 of its 4 runs" in caption and "1 seed per cell" in caption, caption


def test_executed_notebooks_show_their_figures_and_tables_inline(tiny_repo):
    import nbformat

    paths = sorted((tiny_repo / "results/tiny/notebooks").rglob("*.ipynb"))
    assert len([p for p in paths if p.parent.name == "train"]) == 2 and len(paths) == 12, paths
    for path in paths:
        nb = nbformat.read(path, as_version=4)
        outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
        assert not [o for o in outputs if o.output_type == "error"], path
        assert not [o for o in outputs if o.output_type == "stream" and o.name == "stderr"], (path, "stderr output")
        images = [o for o in outputs if "image/png" in o.get("data", {})]
        assert len(images) >= FIGURES_SHOWN.get(path.stem, 1 if path.parent.name == "train" else 0), (path, len(images))
        assert not any("<Figure size" in o.get("data", {}).get("text/plain", "") and "image/png" not in o["data"]
                       for o in outputs), (path, "a figure shown as text only")
        if path.stem in ("02_rewards", "03_ood_detection", "06_paper_vs_us"):
            assert any("| method" in o.get("data", {}).get("text/markdown", "") for o in outputs), path
        assert "papermill" not in nb.metadata and not any("execution" in c.metadata for c in nb.cells), path
        text = "\n".join(json.dumps(o.get("data", {}).get("text/plain", "")) + json.dumps(o.get("text", ""))
                         for o in outputs)  # what a reader sees: no machine detail (paths, memory addresses)
        assert str(tiny_repo) not in text and str(Path.home()) not in text, (path, "a path of this machine")
        assert not re.search(r"0x[0-9a-f]{8,}", text), (path, "a memory address")


def test_rebuilding_plays_nothing_and_gives_the_same_bytes_twice(tiny_repo):
    """The main command ran twice with no environment buildable; the second left the committed tree as it was."""
    assert _git(tiny_repo, "status", "--porcelain") == "?? second_rebuild.log\n"  # only the log of that second run
    second = (tiny_repo / "second_rebuild.log").read_text()
    assert "Running stage 'quickstart'" in second and "Running stage 'example_states'" in second, second
    # the guard is real: in that world, building any env fails with the message below
    probe = "from paper_lib.agents.envs import make_single_env; make_single_env('HalfCheetah-v5')"
    done = _run([str(BIN / "python"), "-c", probe], tiny_repo, {"PYTHONPATH": str(tiny_repo / "tests" / "no_env")})
    assert done.returncode == 1 and "the rebuild tried to build an environment" in done.stderr, done.stderr[-2000:]


def test_a_stage_with_a_missing_checkpoint_fails_clearly_and_writes_nothing(tiny_repo, tmp_path):
    repo = _copy_repo(tmp_path / "broken")
    shutil.copytree(tiny_repo / "results", repo / "results")
    shutil.copy2(tiny_repo / "params.yaml", repo / "params.yaml")
    (repo / "results/tiny/checkpoints/HalfCheetah-v5/masksembles/seed0/model.zip").unlink()
    evaluation = repo / "results/tiny/evaluations/HalfCheetah-v5/masksembles/seed0.csv"
    evaluation.unlink()
    done = _run([str(BIN / "python"), "-m", "paper_lib.pipeline.run_results", "evaluate", "HalfCheetah-v5", "masksembles", "0"],
                repo)
    assert done.returncode == 2
    assert "model.zip is missing" in done.stderr and "dvc repro -f -s train@" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not evaluation.exists(), "no partial evaluation left behind"


def test_verify_recomputes_committed_results_aside_and_finds_a_changed_number(tiny_repo):
    """`python -m paper_lib.pipeline.verify`: same seed, same machine, same files; an edited committed number is found."""
    verify = [str(BIN / "python"), "-m", "paper_lib.pipeline.verify", "--all", "--stages", "evaluate", "score"]
    before = _git(tiny_repo, "status", "--porcelain")
    done = _run(verify, tiny_repo)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert ("14 of 14 files the same as the committed ones or within tolerance (2 run(s), stages evaluate, score)"
            in done.stdout), done.stdout
    assert _git(tiny_repo, "status", "--porcelain") == before, "verify writes nothing under results/"

    metrics = tiny_repo / "results/tiny/scores/HalfCheetah-v5/masksembles/seed0/metrics.csv"
    committed = metrics.read_text()
    header, first, *rest = committed.splitlines(keepends=True)
    auroc = header.split(",").index("auroc")
    cells = first.split(",")
    # a tiny run has 40 states a side, so float noise may swap a few states' worth of AUROC (verify's tolerance,
    # 5/(n_id + n_ood) here): the edit must be larger than that to be a change, as 0.01 is at the paper's sizes
    value = float(cells[auroc])
    cells[auroc] = repr(value - 0.3 if value > 0.5 else value + 0.3)
    try:
        metrics.write_text("".join([header, ",".join(cells), *rest]))
        done = _run([str(BIN / "python"), "-m", "paper_lib.pipeline.verify", "--run", "HalfCheetah-v5", "masksembles", "0"],
                    tiny_repo)
    finally:
        metrics.write_text(committed)
    assert done.returncode == 1, done.stdout[-3000:] + done.stderr[-3000:]
    row = next(line for line in done.stdout.splitlines() if "| metrics.csv" in line)
    assert "numbers differ" in row and "auroc" in row and "0.3" in row, done.stdout
    assert "5 of 6 files within tolerance" in done.stdout, done.stdout
