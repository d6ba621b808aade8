"""The whole DVC pipeline on the `tiny` profile, in a temporary copy of the repository."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _copy_repo(dst: Path) -> Path:
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, check=True,
                           capture_output=True, text=True).stdout.split()
    for rel in files:
        if rel.startswith("results/"):
            continue
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, target)
    subprocess.run(["git", "init", "-q"], cwd=dst, check=True)
    return dst


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg"}
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True)


@pytest.fixture(scope="module")
def tiny_repo(tmp_path_factory) -> Path:
    repo = _copy_repo(tmp_path_factory.mktemp("repo"))
    done = _run([str(BIN / "python"), "-m", "paper_lib.config", "use", "tiny"], repo)
    assert done.returncode == 0, done.stderr
    done = _run([str(BIN / "dvc"), "repro"], repo)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return repo


def _declared_outputs(repo: Path) -> list[Path]:
    import yaml

    lock = yaml.safe_load((repo / "dvc.lock").read_text())  # also holds the committed profile's stages
    outs = [out["path"] for stage in lock["stages"].values() for out in stage.get("outs", [])]
    return [repo / path for path in outs if path.startswith("results/tiny/")]


def test_tiny_pipeline_produces_every_table_and_figure(tiny_repo):
    results = tiny_repo / "results" / "tiny"
    outputs = _declared_outputs(tiny_repo)
    assert len(outputs) > 30
    for out in outputs:
        assert out.exists(), out
        files = [out] if out.is_file() else [p for p in out.rglob("*") if p.is_file()]
        assert files, f"{out} is empty"
        assert all(f.stat().st_size > 0 for f in files), out
    for stem in ("rewards", "ood_auroc_perturbed", "ood_auroc_noise", "ood_metrics", "paper_vs_us_rewards",
                 "paper_vs_us_auroc", "perturbation_ratios"):
        for suffix in (".csv", ".md", ".tex"):
            assert (results / "tables" / f"{stem}{suffix}").stat().st_size > 0
    for stem in ("training_curves", "roc_value_policy", "roc_policy_js"):
        for suffix in (".png", ".pdf"):
            assert (results / "figures" / f"{stem}{suffix}").stat().st_size > 0
    assert list((results / "figures" / "over_time").glob("*.png"))
    assert list((results / "figures" / "perturbation_bars").glob("*.png"))
    caption = (results / "tables" / "rewards.md").read_text().splitlines()[0]
    assert "profile 'tiny'" in caption and "1 seed" in caption


def test_second_repro_retrains_nothing_and_status_is_clean(tiny_repo):
    done = _run([str(BIN / "dvc"), "status"], tiny_repo)
    assert done.returncode == 0
    assert "changed" not in done.stdout, done.stdout
    done = _run([str(BIN / "dvc"), "repro", "--dry"], tiny_repo)
    assert "Running stage" not in done.stdout, done.stdout


def test_a_stage_with_a_missing_checkpoint_fails_clearly_and_writes_no_table(tiny_repo, tmp_path):
    repo = _copy_repo(tmp_path / "broken")
    shutil.copytree(tiny_repo / "results", repo / "results")
    shutil.copy2(tiny_repo / "dvc.lock", repo / "dvc.lock")
    shutil.copy2(tiny_repo / "params.yaml", repo / "params.yaml")
    ckpt = repo / "results/tiny/checkpoints/HalfCheetah-v5/masksembles/seed0/model.zip"
    ckpt.unlink()
    tables = repo / "results/tiny/tables"
    for f in tables.glob("rewards*"):
        f.unlink()
    done = _run([str(BIN / "papermill"), "-k", "python3", "notebooks/02_rewards.ipynb", str(tmp_path / "out.ipynb")], repo)
    assert done.returncode != 0
    assert "model.zip is missing" in done.stdout + done.stderr
    assert "dvc repro -f -s train@" in done.stdout + done.stderr
    assert not list(tables.glob("rewards*")), "no partial table left behind"
