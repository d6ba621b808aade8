"""`make reproduce` picks the stages whose inputs exist (the ensembles part runs with `own` runs alone) and says
in runs.md what the missing runs will cost."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.reproduce import experiment_stages, make_ensemble_folders, table_stages
from paper_lib.pipeline.status import remaining_training_line, training_time_line

REPO = Path(__file__).resolve().parents[2]


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


def test_the_pedm_protocol_table_waits_for_a_run_that_played_pedms_protocol(tmp_path: Path):
    """Its DVC dep, results/<profile>/pedm, exists only once a `pedm` stage ran: until a run has metrics, skipped."""
    cfg = dataclasses.replace(_empty_profile(tmp_path), envs=["HalfCheetah-v5"], methods=["baseline"], seeds=[0])
    stages, skipped = table_stages(cfg)
    assert "pedm_protocol" not in stages
    assert any(line.startswith("pedm_protocol: skipped, no MuJoCo run has played PEDM's protocol") for line in skipped)
    folder = cfg.layout.pedm_dir("HalfCheetah-v5", "baseline", 0)
    folder.mkdir(parents=True)
    assert "pedm_protocol" not in table_stages(cfg)[0]  # a folder without metrics is no run
    (folder / "metrics.csv").write_text("scorer,kind\n")
    assert "pedm_protocol" in table_stages(cfg)[0]


def test_runs_md_estimates_the_missing_training_from_the_trained_runs(tmp_path: Path):
    cfg = dataclasses.replace(_empty_profile(tmp_path), envs=["Swimmer-v5", "SeaquestNoFrameskip-v4"],
                              methods=["baseline", "ensemble"], seeds=[0, 1])
    for (env_id, method, seed), minutes in {("Swimmer-v5", "baseline", 0): 10, ("Swimmer-v5", "ensemble", 0): 30,
                                            ("SeaquestNoFrameskip-v4", "baseline", 0): 90}.items():
        folder = cfg.checkpoint_dir(env_id, method, seed)
        folder.mkdir(parents=True)
        (folder / "config.json").write_text(json.dumps({"wall_seconds": minutes * 60}))
    gpu_begun = cfg.checkpoint_dir("SeaquestNoFrameskip-v4", "baseline", 1)
    gpu_begun.mkdir(parents=True)
    (gpu_begun / "config.json").write_text(json.dumps({"wall_seconds": 600, "segments": [
        {"from_step": 0, "to_step": 400, "device": "cuda"}, {"from_step": 400, "to_step": 1000, "device": "cpu"}]}))
    (gpu_begun / "model.zip").write_bytes(b"")
    # missing: Swimmer baseline 1 (10 min), Swimmer ensemble 1 (30), Seaquest ensemble 0 and 1 (no Atari
    # ensemble trained: not estimated); Seaquest baseline 1 began on a GPU: not a measure of this CPU
    line = remaining_training_line(cfg)
    assert line.startswith("The 4 runs without a checkpoint need about 0.7 core-hours more"), line
    assert line.endswith("2 of them have no trained run of their method and kind to estimate from."), line
    times = training_time_line(cfg)
    assert times.startswith("Training wall time of the 3 runs trained on the CPU: 2.2 h in total"), times
    assert "10-90 min a run (1 run begun on a lent GPU is left out" in times, times


def test_the_committed_run_list_names_exactly_the_runs_with_a_committed_checkpoint():
    """runs.yaml gives dvc.yaml its per-run stages: a run listed without a checkpoint would make `dvc repro` train it."""
    from paper_lib.pipeline.config import load_run_config
    from paper_lib.pipeline.run_list import RUN_LIST, run_list_text
    from paper_lib.pipeline.status import available_runs

    repo = Path(__file__).resolve().parents[2]
    cfg = load_run_config(repo / "params.yaml")
    assert (repo / RUN_LIST).read_text() == run_list_text(cfg, available_runs(cfg, "checkpoint")), (
        "runs.yaml is out of date: write it with `python -m paper_lib.pipeline.run_list` and commit it")


def test_a_recollection_reports_each_rewritten_file_against_the_one_it_replaced(tmp_path, capsys):
    from paper_lib.pipeline.reproduce import report_recollection

    before, after = tmp_path / "before", tmp_path / "after"
    before.mkdir(), after.mkdir()
    for name, old, new in [("noise.csv", "m,auroc\na,0.9\n", "m,auroc\na,0.9000001\n"),
                           ("moved.csv", "m,auroc\na,0.9\n", "m,auroc\na,0.7\n")]:
        (before / name).write_text(old)
        (after / name).write_text(new)
    outside = report_recollection({after / name: before / name for name in ("noise.csv", "moved.csv")})
    printed = capsys.readouterr().out
    assert outside == 1 and "1 of 2 evaluation and score files within" in printed
    assert "moved.csv: numbers differ (largest difference 0.2 in auroc" in printed and "noise.csv" not in printed


def test_only_the_per_run_stages_dvc_status_finds_stale_are_named_to_dvc_repro():
    """Naming a stage to `dvc repro` costs a dvc.yaml load (~7 s): the up-to-date ones are left out, in stage order."""
    from paper_lib.pipeline.reproduce import per_run_targets

    runs = [("Swimmer-v5", "baseline", 0), ("Swimmer-v5", "masksembles", 0), ("SeaquestNoFrameskip-v4", "baseline", 0)]
    everything = per_run_targets(runs, None)
    assert everything == [["score@Swimmer-v5-baseline-0", "score@Swimmer-v5-masksembles-0",
                           "score@SeaquestNoFrameskip-v4-baseline-0"],
                          ["common_score@Swimmer-v5-masksembles-0"],
                          ["sequence_score@Swimmer-v5-baseline-0", "sequence_score@Swimmer-v5-masksembles-0"]]
    stale = {"score@Swimmer-v5-masksembles-0", "sequence_score@Swimmer-v5-masksembles-0", "ood", "guard",
             "collect@Swimmer-v5-baseline-0"}  # tables and simulating stages are not this step's
    assert per_run_targets(runs, stale) == [["score@Swimmer-v5-masksembles-0"],
                                            ["sequence_score@Swimmer-v5-masksembles-0"]]
    assert per_run_targets(runs, set()) == []
