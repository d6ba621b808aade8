"""Issue 41, the hash chain: scores record what they were made from, and readers refuse scores whose inputs changed.

One tiny-profile run pair (HalfCheetah baseline and Masksembles, seed 0) is trained, collected and scored for real in a
temporary tree; each test works on its own copy of that tree.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from paper_lib.common.io import DestinationError
from paper_lib.common.provenance import file_digest
from paper_lib.ood.datasets import OOD_LABEL, StateDataset
from paper_lib.pipeline.config import RunConfig, load_run_config
from paper_lib.pipeline.run_results import (PROVENANCE_FILE, check_score_provenance, read_all_replicates, read_scores,
                                            read_source_coverage, record_provenance, score_run_files, scores_dir)
from paper_lib.pipeline.stages import collect_run, train_stage

REPO = Path(__file__).resolve().parents[2]
ENV = "HalfCheetah-v5"
RUNS = [(ENV, "baseline", 0), (ENV, "masksembles", 0)]


def tiny_params(folder: Path) -> Path:
    """The project's params.yaml with the tiny profile active (what `config use tiny` writes), in `folder`."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["run"] = {"profile": "tiny", **params["profiles"]["tiny"]}
    path = folder / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


def config(root: Path) -> RunConfig:
    return dataclasses.replace(load_run_config(root / "params.yaml"), root=root)


def snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*"))}


@pytest.fixture(scope="module")
def scored(tmp_path_factory) -> Path:
    """A tree with both tiny runs trained, collected and scored (provenance.json written by the score stage)."""
    root = tmp_path_factory.mktemp("scored")
    tiny_params(root)
    cfg = config(root)
    for run in RUNS:
        train_stage(cfg, *run)
        collect_run(cfg, *run)
        score_run_files(cfg, *run)
    return root


@pytest.fixture
def tree(scored, tmp_path) -> Path:
    """This test's own copy of the scored tree."""
    root = tmp_path / "tree"
    shutil.copytree(scored, root, symlinks=True)
    return root


def test_the_score_stage_records_its_inputs_without_time_or_path(tree):
    cfg = config(tree)
    for run in RUNS:
        path = scores_dir(cfg, *run) / PROVENANCE_FILE
        recorded = json.loads(path.read_text())
        assert (recorded["env"], recorded["method"], recorded["seed"]) == run
        checkpoint = cfg.checkpoint_dir(*run)
        assert recorded["sha256"] == {"dataset": file_digest(cfg.dataset_path(*run)),
                                      **{name: file_digest(checkpoint / name) for name in ("model.zip", "vecnormalize.pkl")
                                         if (checkpoint / name).is_file()}}
        text = path.read_text()
        assert str(tree) not in text and str(REPO) not in text and "tmp" not in text
    before = (scores_dir(cfg, *RUNS[1]) / PROVENANCE_FILE).read_bytes()
    score_run_files(cfg, *RUNS[1])  # the same inputs scored again: the same bytes
    assert (scores_dir(cfg, *RUNS[1]) / PROVENANCE_FILE).read_bytes() == before
    assert len(read_scores(cfg, RUNS, "metrics")) > 0 and read_all_replicates(cfg, RUNS)


def _edit_dataset(cfg: RunConfig, run: tuple[str, str, int]) -> Path:
    """The run's dataset collected 'again': the same states, one metadata entry different."""
    path = cfg.dataset_path(*run)
    data = StateDataset.load(path)
    data.metadata["recollected"] = True
    data.save(path)
    return path


def test_scores_of_a_changed_dataset_are_refused_naming_both(tree):
    cfg = config(tree)
    dataset = _edit_dataset(cfg, RUNS[1])
    before = snapshot(tree)
    folder = scores_dir(cfg, *RUNS[1])
    for read in (lambda: read_scores(cfg, RUNS, "metrics"), lambda: read_all_replicates(cfg, RUNS)):
        with pytest.raises(ValueError, match=rf"the scores {folder} were made from dataset SHA-256 [0-9a-f]{{12}}\.\.\., "
                                             rf"but {dataset} is now [0-9a-f]{{12}}\.\.\.: they are stale .* score the run "
                                             rf"again \(`python -m paper_lib.pipeline.run_results score {ENV} masksembles 0`\)"):
            read()
    read_scores(cfg, RUNS[:1], "metrics")  # the other run is fine
    assert snapshot(tree) == before


def test_scores_of_a_changed_checkpoint_are_refused(tree):
    cfg = config(tree)
    model = cfg.checkpoint_dir(*RUNS[0]) / "model.zip"
    with open(model, "ab") as f:
        f.write(b"\0")
    with pytest.raises(ValueError, match=rf"made from model\.zip SHA-256 .* but {model} is now"):
        read_scores(cfg, RUNS, "roc")


def test_another_runs_scores_at_a_runs_path_are_refused(tree):
    """Masksembles' scores folder copied over the baseline's: its provenance names masksembles."""
    cfg = config(tree)
    baseline, masksembles = scores_dir(cfg, *RUNS[0]), scores_dir(cfg, *RUNS[1])
    shutil.rmtree(baseline)
    shutil.copytree(masksembles, baseline)
    with pytest.raises(ValueError, match=rf"{baseline / PROVENANCE_FILE} belongs to {ENV} masksembles seed 0, not to "
                                         rf"{ENV} baseline seed 0 whose path it sits at"):
        read_scores(cfg, RUNS, "over_time")


def test_scores_without_a_record_are_refused_by_the_readers_and_an_unreadable_record_too(tree):
    """Issue 71: a folder without its record could hold any run's files; the readers refuse it, naming the backfill."""
    cfg = config(tree)
    path = scores_dir(cfg, *RUNS[0]) / PROVENANCE_FILE
    path.unlink()  # scores made before the record existed
    check_score_provenance(cfg, *RUNS[0])  # the check itself passes it over where not required
    for read in (lambda: read_scores(cfg, RUNS[:1], "perturbation_ratios"), lambda: read_all_replicates(cfg, RUNS[:1])):
        with pytest.raises(ValueError, match=rf"the scores {path.parent} have no provenance\.json: .* record it from the "
                                             rf"current files, which the command checks first \(`python -m "
                                             rf"paper_lib\.pipeline\.run_results provenance {ENV} baseline 0`\)"):
            read()
    assert read_source_coverage(cfg, RUNS).empty  # MuJoCo: no coverage rows, no record needed
    for text in ('{"env": "HalfCheetah-v5",', '{"env": "HalfCheetah-v5", "method": "baseline", "seed": 0}'):
        path.write_text(text)  # cut off; whole JSON but not a record (no format, no digests)
        with pytest.raises(ValueError, match=rf"{path} is not a readable provenance record"):
            read_scores(cfg, RUNS, "metrics")


def test_the_source_coverage_reader_checks_the_record_too(tree):
    """An Atari run's scores folder that is another run's (copied there): refused before its coverage row is read."""
    cfg = config(tree)
    atari = ("PongNoFrameskip-v4", "masksembles", 0)
    shutil.copytree(scores_dir(cfg, *RUNS[1]), scores_dir(cfg, *atari))
    (scores_dir(cfg, *atari) / "source_coverage.csv").write_text("env,method,seed\nPongNoFrameskip-v4,masksembles,0\n")
    with pytest.raises(ValueError, match=rf"belongs to {ENV} masksembles seed 0, not to PongNoFrameskip-v4 masksembles"):
        read_source_coverage(cfg, [*RUNS, atari])


def test_a_missing_input_is_passed_over_not_guessed(tree):
    """A checkout without datasets cannot compare them; the checkpoint is still compared."""
    cfg = config(tree)
    cfg.dataset_path(*RUNS[1]).unlink()
    read_scores(cfg, RUNS, "metrics")
    with open(cfg.checkpoint_dir(*RUNS[1]) / "model.zip", "ab") as f:
        f.write(b"\0")
    with pytest.raises(ValueError, match=r"made from model\.zip"):
        read_scores(cfg, RUNS, "metrics")


# ----------------------------------------------------------------------------- the backfill command


def cli(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "paper_lib.pipeline.run_results", *args], cwd=root,
                          capture_output=True, text=True, timeout=300)


def test_backfill_writes_the_record_the_score_stage_writes_and_is_idempotent(tree):
    cfg = config(tree)
    written = {run: (scores_dir(cfg, *run) / PROVENANCE_FILE).read_bytes() for run in RUNS}
    for run in RUNS:
        (scores_dir(cfg, *run) / PROVENANCE_FILE).unlink()
    done = cli(tree, "provenance")
    assert done.returncode == 0, done.stderr
    assert "2 provenance record(s) written, 0 already there (2 scored runs of profile 'tiny')" in done.stdout
    assert {run: (scores_dir(cfg, *run) / PROVENANCE_FILE).read_bytes() for run in RUNS} == written  # byte-identical
    before = snapshot(tree)
    done = cli(tree, "provenance")
    assert done.returncode == 0 and "0 provenance record(s) written, 2 already there" in done.stdout, done.stderr
    done = cli(tree, "provenance", ENV, "baseline", "0")
    assert done.returncode == 0 and "already recorded" in done.stdout, done.stderr
    assert snapshot(tree) == before


def test_backfill_refuses_a_changed_input_and_writes_nothing(tree):
    """A record naming other inputs is never overwritten with the current ones: that would bless stale scores."""
    cfg = config(tree)
    (scores_dir(cfg, *RUNS[0]) / PROVENANCE_FILE).unlink()  # this one could be backfilled ...
    dataset = _edit_dataset(cfg, RUNS[1])  # ... but this one's record names the old dataset
    before = snapshot(tree)
    done = cli(tree, "provenance")
    assert done.returncode == 2, done.stderr
    assert "made from dataset SHA-256" in done.stderr and f"but {dataset.relative_to(tree)} is now" in done.stderr
    assert snapshot(tree) == before  # all runs checked before any record is written


def test_backfill_refuses_another_runs_scores_or_dataset(tree):
    cfg = config(tree)
    baseline = scores_dir(cfg, *RUNS[0])
    for run in RUNS:
        (scores_dir(cfg, *run) / PROVENANCE_FILE).unlink()
    masksembles_metrics = (scores_dir(cfg, *RUNS[1]) / "metrics.csv").read_bytes()
    kept = (baseline / "metrics.csv").read_bytes()
    (baseline / "metrics.csv").write_bytes(masksembles_metrics)
    before = snapshot(tree)
    with pytest.raises(ValueError, match=rf"{baseline / 'metrics.csv'} belongs to {ENV} masksembles seed 0, not to "
                                         rf"{ENV} baseline seed 0"):
        record_provenance(cfg, RUNS)
    assert snapshot(tree) == before
    (baseline / "metrics.csv").write_bytes(kept)
    shutil.copy(cfg.dataset_path(*RUNS[1]), cfg.dataset_path(*RUNS[0]))
    before = snapshot(tree)
    with pytest.raises(ValueError, match=rf"{cfg.dataset_path(*RUNS[0])} belongs to {ENV} masksembles seed 0"):
        record_provenance(cfg, RUNS)
    assert snapshot(tree) == before


# ----------------------------------------------------------------------------- the score stage's door


def test_scoring_into_a_foreign_folder_is_refused_before_any_work(tree):
    """A folder of someone's files at a run's scores path: the swap would delete them. The run below has no checkpoint:
    the refusal comes first, before anything is loaded."""
    cfg = config(tree)
    folder = scores_dir(cfg, ENV, "mc_dropout", 0)
    folder.mkdir(parents=True)
    (folder / "notes.txt").write_text("mine\n")
    before = snapshot(tree)
    with pytest.raises(DestinationError, match=rf"scores folder {folder} holds files but none of a scores folder's "
                                               r"\(metrics\.csv, .*provenance\.json\).*move those files away"):
        score_run_files(cfg, ENV, "mc_dropout", 0)
    assert snapshot(tree) == before
    score_run_files(cfg, *RUNS[0])  # a scores folder of ours is replaced as before


# ----------------------------------------------------------------------------- labels against their sources


def test_a_dataset_whose_labels_contradict_their_sources_is_refused_by_the_score_stage(tree):
    cfg = config(tree)
    path = cfg.dataset_path(*RUNS[1])
    data = StateDataset.load(path)
    ids = np.flatnonzero(data.labels == 0)[:3]
    data.labels[ids] = OOD_LABEL  # three ID states (source 'id') labelled OOD
    data.save(path)
    before = snapshot(tree)
    with pytest.raises(ValueError, match=rf"{path}: 3 of {len(data)} states have a label that contradicts their source "
                                         rf"\(e\.g\. state {ids[0]}: source 'id' labelled OOD\)"):
        score_run_files(cfg, *RUNS[1])
    assert snapshot(tree) == before
