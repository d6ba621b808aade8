"""Issue 41 for the ensembles: their scores record what they were made from, and notebook 11's readers refuse scores
whose record is missing or names other files than the ones there now.

A tiny tree is trained, collected, evaluated and scored for real: three Walker2d members (they normalize), whose
2-of-3 combinations are assembled, and one `own` run with its shared twin; each test works on its own copy.
"""

from __future__ import annotations

import copy
import hashlib
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from paper_lib.common.io import DestinationError
from paper_lib.common.provenance import file_digest
from paper_lib.experiments import ensembles as ens
from paper_lib.experiments.ensembles_report import read_independent, read_own_vs_shared
from paper_lib.pipeline.run_results import PROVENANCE_FILE
from paper_lib.pipeline.stages import train_stage

REPO = Path(__file__).resolve().parents[2]
ENV = "Walker2d-v5"
RUN = (ENV, "masksembles", 0)
MEMBERS = [0, 1, 2]
SECTION = {"rule": {"budget_fraction": 0.25, "epochs_factor": 4, "ensemble_size": 2},
           "profiles": {"tiny": {"independent": {"envs": [ENV], "member_seeds": MEMBERS, "total_timesteps": None},
                                 "own_vs_shared": {"envs": [ENV], "methods": ["masksembles"], "seeds": [0]}}}}
BACKFILL = re.escape("`python -m paper_lib.experiments.ensembles provenance`")


def write_params(folder: Path) -> Path:
    """The project's params.yaml with the tiny profile active and this small `ensembles` section."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["run"] = {"profile": "tiny", **copy.deepcopy(params["profiles"]["tiny"])}
    params["ensembles"] = SECTION
    path = folder / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


def snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*"))}


def quiet(line: str) -> None:
    pass


@pytest.fixture(scope="module")
def scored(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ensembles")
    cfg = ens.load_ensembles_config(write_params(root))
    for seed in MEMBERS:
        ens.train_member(cfg, ENV, seed)
    ens.train_own(cfg, *RUN)
    train_stage(cfg.run, *RUN)  # the shared twin, as the main matrix trains it (outside the tiny main matrix)
    ens.collect_all(cfg, log=quiet)
    ens.evaluate_all(cfg, log=quiet)  # scores every combination and both twins, each with its provenance.json
    return root


@pytest.fixture
def cfg(scored, tmp_path) -> ens.EnsemblesConfig:
    """This test's own copy of the scored tree."""
    root = tmp_path / "tree"
    shutil.copytree(scored, root, symlinks=True)
    return ens.load_ensembles_config(root / "params.yaml")


def combo(cfg: ens.EnsemblesConfig, members: tuple[int, ...]) -> Path:
    return ens.combination_scores_dir(cfg, ENV, members)


def own_folder(cfg: ens.EnsemblesConfig) -> Path:
    return cfg.own.layout.scores_dir(*RUN)


def cli(cfg: ens.EnsemblesConfig, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "paper_lib.experiments.ensembles", *args], cwd=cfg.run.root,
                          capture_output=True, text=True, timeout=300)


def swap_member(cfg: ens.EnsemblesConfig, seed: int, other: int) -> Path:
    """Member `other`'s checkpoint files copied over member `seed`'s (its config.json stays: it still looks right)."""
    for name in ("model.zip", "vecnormalize.pkl"):
        shutil.copy(cfg.member_dir(ENV, other) / name, cfg.member_dir(ENV, seed) / name)
    return cfg.member_dir(ENV, seed) / "model.zip"


def made_from(folder: Path, name: str, was: str, path: Path, now: str) -> str:
    return (rf"the scores {re.escape(str(folder))} were made from {re.escape(name)} SHA-256 {was[:12]}\.\.\., "
            rf"but {re.escape(str(path))} is now {now[:12]}\.\.\.: they are stale or another run's")


# ----------------------------------------------------------------------------- the writer


def test_the_score_writer_records_the_dataset_and_each_members_files(cfg):
    assert cfg.combinations() == [(0, 1), (0, 2), (1, 2)]
    for members in cfg.combinations():
        path = combo(cfg, members) / PROVENANCE_FILE
        record = json.loads(path.read_text())
        assert {k: record[k] for k in ("env", "method", "members")} == {"env": ENV, "method": "independent_ensemble",
                                                                        "members": list(members)}
        assert "seed" not in record
        assert record["sha256"] == {"dataset": file_digest(cfg.combination_dataset(ENV, members)),
                                    **{f"seed{s}/{name}": file_digest(cfg.member_dir(ENV, s) / name)
                                       for s in members for name in ("model.zip", "vecnormalize.pkl")}}
        assert str(cfg.run.root) not in path.read_text() and "tmp" not in path.read_text()  # no path, no time
    record = json.loads((own_folder(cfg) / PROVENANCE_FILE).read_text())  # an own run: the main matrix's record
    checkpoint = cfg.own.checkpoint_dir(*RUN)
    assert (record["env"], record["method"], record["seed"]) == RUN
    assert record["sha256"] == {"dataset": file_digest(cfg.own.dataset_path(*RUN)),
                                **{name: file_digest(checkpoint / name) for name in ("model.zip", "vecnormalize.pkl")}}
    independent, own_vs_shared = read_independent(cfg), read_own_vs_shared(cfg)
    assert set(independent.metrics["members"]) == {"members-0-1", "members-0-2", "members-1-2"}
    assert set(own_vs_shared.metrics["assignment"]) == {"shared", "own"}
    before = (combo(cfg, (0, 2)) / PROVENANCE_FILE).read_bytes()
    shutil.rmtree(combo(cfg, (0, 2)))
    ens.score_combination(cfg, ENV, 1, (0, 2))  # the same files scored again: the same record, byte for byte
    assert (combo(cfg, (0, 2)) / PROVENANCE_FILE).read_bytes() == before


def test_scoring_into_a_foreign_folder_or_from_another_combinations_dataset_is_refused(cfg):
    folder = combo(cfg, (0, 1))
    shutil.rmtree(folder)
    folder.mkdir()
    (folder / "notes.txt").write_text("mine\n")
    before = snapshot(cfg.run.root)
    for score in (lambda: ens.score_combination(cfg, ENV, 0, (0, 1)), lambda: ens.evaluate_all(cfg, log=quiet)):
        with pytest.raises(DestinationError, match=rf"scores folder {re.escape(str(folder))} holds files but none of a "
                                                   r"scores folder's \(metrics\.csv, provenance\.json\)"):
            score()
        assert snapshot(cfg.run.root) == before  # refused before any work
    shutil.rmtree(folder)
    dataset = cfg.combination_dataset(ENV, (0, 1))
    shutil.copy(cfg.combination_dataset(ENV, (0, 2)), dataset)
    with pytest.raises(ValueError, match=rf"{re.escape(str(dataset))} was collected by {ENV} independent_ensemble of 2 "
                                         rf"members with ID seed 1001, not by {ENV} members-0-1 \(combination 0"):
        ens.score_combination(cfg, ENV, 0, (0, 1))
    assert not folder.exists()


# ----------------------------------------------------------------------------- the readers


def test_a_swapped_member_checkpoint_is_refused_naming_both_digests(cfg):
    member = cfg.member_dir(ENV, 1) / "model.zip"
    was, now = file_digest(member), file_digest(cfg.member_dir(ENV, 2) / "model.zip")
    swap_member(cfg, 1, 2)
    assert ens.member_problem(cfg, ENV, 1) is None  # its config.json still says seed 1: only the digests tell
    with pytest.raises(ValueError, match=made_from(combo(cfg, (0, 1)), "seed1/model.zip", was, member, now)):
        read_independent(cfg)


def test_another_dataset_is_refused_naming_both_digests(cfg):
    dataset = cfg.combination_dataset(ENV, (0, 1))
    was, now = file_digest(dataset), file_digest(cfg.combination_dataset(ENV, (0, 2)))
    shutil.copy(cfg.combination_dataset(ENV, (0, 2)), dataset)
    with pytest.raises(ValueError, match=made_from(combo(cfg, (0, 1)), "dataset", was, dataset, now) +
                       r".*move .* away, then `python -m paper_lib\.experiments\.ensembles evaluate`"):
        read_independent(cfg)


def test_another_combinations_record_is_refused_naming_both(cfg):
    path = combo(cfg, (0, 1)) / PROVENANCE_FILE
    shutil.copy(combo(cfg, (0, 2)) / PROVENANCE_FILE, path)
    with pytest.raises(ValueError, match=rf"{re.escape(str(path))} belongs to {ENV} independent_ensemble members-0-2, "
                                         rf"not to {ENV} independent_ensemble members-0-1 whose path it sits at"):
        read_independent(cfg)


def test_an_own_runs_scores_made_from_the_shared_twins_files_are_refused(cfg):
    own, shared = own_folder(cfg), cfg.shared.layout.scores_dir(*RUN)
    shutil.rmtree(own)
    shutil.copytree(shared, own)  # the shared twin's scores at the own run's path: the same run identity, other files
    dataset = cfg.own.dataset_path(*RUN)
    was, now = file_digest(cfg.shared.dataset_path(*RUN)), file_digest(dataset)
    with pytest.raises(ValueError, match=made_from(own, "dataset", was, dataset, now)):
        read_own_vs_shared(cfg)


def test_scores_without_a_record_or_with_an_unreadable_one_are_refused_naming_the_backfill(cfg):
    for folder, read, who in ((combo(cfg, (1, 2)), read_independent, f"{ENV} independent_ensemble members-1-2"),
                              (own_folder(cfg), read_own_vs_shared, f"{ENV} masksembles seed 0")):
        path = folder / PROVENANCE_FILE
        path.unlink()
        with pytest.raises(ValueError, match=rf"the scores {re.escape(str(folder))} have no provenance\.json: .* not "
                                             rf"read as {who}'s; .*{BACKFILL}"):
            read(cfg)
        path.write_text('{"env": "Walker2d-v5",')  # cut off
        unreadable = rf"{re.escape(str(path))} is not a readable provenance record.*{BACKFILL}"
        with pytest.raises(ValueError, match=unreadable):
            read(cfg)
        path.unlink()


# ----------------------------------------------------------------------------- the backfill command


def test_backfill_writes_the_writers_records_and_is_idempotent(cfg):
    folders = [combo(cfg, m) for m in cfg.combinations()] + [own_folder(cfg)]
    written = {f: (f / PROVENANCE_FILE).read_bytes() for f in folders}
    for folder in folders:
        (folder / PROVENANCE_FILE).unlink()
    done = cli(cfg, "provenance")
    assert done.returncode == 0, done.stderr
    assert "4 provenance record(s) written, 0 already there (4 scored combinations and own runs of profile 'tiny')" \
        in done.stdout
    assert {f: (f / PROVENANCE_FILE).read_bytes() for f in folders} == written  # byte-identical
    before = snapshot(cfg.run.root)
    done = cli(cfg, "provenance")
    assert done.returncode == 0 and "0 provenance record(s) written, 4 already there" in done.stdout, done.stderr
    assert snapshot(cfg.run.root) == before
    read_independent(cfg), read_own_vs_shared(cfg)


def _unrecorded(cfg: ens.EnsemblesConfig, *folders: Path) -> None:
    for folder in folders:
        (folder / PROVENANCE_FILE).unlink()


def test_backfill_refuses_a_changed_member_and_writes_nothing(cfg):
    """(0, 1) could be recorded, but (1, 2)'s record names member 1's old files: nothing is written."""
    _unrecorded(cfg, combo(cfg, (0, 1)))
    member = cfg.member_dir(ENV, 1) / "model.zip"
    was, now = file_digest(member), file_digest(cfg.member_dir(ENV, 2) / "model.zip")
    swap_member(cfg, 1, 2)
    before = snapshot(cfg.run.root)
    done = cli(cfg, "provenance")
    assert done.returncode == 2, done.stderr
    assert re.search(made_from(combo(cfg, (1, 2)).relative_to(cfg.run.root), "seed1/model.zip", was,
                               member.relative_to(cfg.run.root), now), done.stderr), done.stderr
    assert snapshot(cfg.run.root) == before


def test_backfill_refuses_another_combinations_metrics_or_dataset(cfg):
    _unrecorded(cfg, *(combo(cfg, m) for m in cfg.combinations()))
    metrics = combo(cfg, (0, 1)) / "metrics.csv"
    kept = metrics.read_bytes()
    shutil.copy(combo(cfg, (0, 2)) / "metrics.csv", metrics)
    before = snapshot(cfg.run.root)
    with pytest.raises(ValueError, match=rf"{re.escape(str(metrics))} belongs to {ENV} independent_ensemble "
                                         rf"members-0-2 \(combination 1\), not to {ENV} independent_ensemble "
                                         rf"members-0-1"):
        ens.record_provenance(cfg)
    assert snapshot(cfg.run.root) == before
    metrics.write_bytes(kept)
    dataset = cfg.combination_dataset(ENV, (0, 1))
    shutil.copy(cfg.combination_dataset(ENV, (1, 2)), dataset)
    before = snapshot(cfg.run.root)
    with pytest.raises(ValueError, match=rf"{re.escape(str(dataset))} was collected by .* ID seed 2001, not by {ENV} "
                                         r"members-0-1 \(combination 0: 2 members, ID seed 1\)"):
        ens.record_provenance(cfg)
    assert snapshot(cfg.run.root) == before


def test_backfill_refuses_an_own_run_holding_its_shared_twins_files(cfg):
    _unrecorded(cfg, own_folder(cfg))
    dataset = cfg.own.dataset_path(*RUN)
    shutil.copy(cfg.shared.dataset_path(*RUN), dataset)  # same run in its metadata: only the bytes tell
    before = snapshot(cfg.run.root)
    with pytest.raises(ValueError, match=rf"{re.escape(str(dataset))} has the same bytes as the shared twin's"):
        ens.record_provenance(cfg)
    assert snapshot(cfg.run.root) == before
