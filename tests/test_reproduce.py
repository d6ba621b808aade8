"""`make reproduce` picks the stages whose inputs exist: the ensembles part runs with `own` runs alone."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from paper_lib.config import load_run_config
from paper_lib.reproduce import experiment_stages, make_ensemble_folders, table_stages

REPO = Path(__file__).resolve().parents[1]


def _empty_profile(tmp_path: Path):
    cfg = load_run_config(REPO / "params.yaml")
    return dataclasses.replace(cfg, profile="tiny", root=tmp_path)


def test_ensembles_stages_wait_for_runs_then_run_with_own_runs_alone(tmp_path: Path):
    cfg = _empty_profile(tmp_path)
    assert "ensembles_scores" not in experiment_stages(cfg)[0]
    own_run = cfg.results / "own" / "checkpoints" / "Swimmer-v5" / "masksembles" / "seed0"
    own_run.mkdir(parents=True)
    assert "ensembles_scores" not in experiment_stages(cfg)[0]  # empty folders are not runs

    (own_run / "model.zip").write_bytes(b"weights")
    assert "ensembles_scores" in experiment_stages(cfg)[0]
    assert not (cfg.results / "independent").exists()
    make_ensemble_folders(cfg)  # DVC needs the declared folders of the part that has no runs
    assert all((cfg.results / "independent" / kind).is_dir()
               for kind in ("checkpoints", "datasets", "evaluations", "scores"))

    assert "ensembles" not in table_stages(cfg)[0]  # nothing scored yet
    (cfg.results / "scores").mkdir()
    scored = cfg.results / "own" / "scores" / "Swimmer-v5" / "masksembles" / "seed0"
    scored.mkdir(parents=True)
    (scored / "ood_metrics.csv").write_text("measure,auroc\n")
    assert "ensembles" in table_stages(cfg)[0]
