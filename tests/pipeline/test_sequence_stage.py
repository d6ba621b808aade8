"""The `sequence_score` stage (issue 69) on a cut-down copy of a committed MuJoCo dataset: same seed, same bytes."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from paper_lib.ood.datasets import StateDataset
from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.sequence_stage import FILES, main, read_sequence_scores, run_sequence_scores

ROOT = Path(__file__).resolve().parents[2]
RUN = ("HalfCheetah-v5", "masksembles", 0)
UNSCORED = ("HalfCheetah-v5", "baseline", 0)


def _config(root: Path):
    """The paper profile over a results tree at `root`, holding RUN's committed dataset cut to 6 ID and 5 OOD
    episodes (its metadata, so its identity, kept)."""
    cfg = load_run_config(ROOT / "params.yaml")
    cfg = cfg.__class__(**{**cfg.__dict__, "root": root})
    data = StateDataset.load(ROOT / "results" / cfg.profile / "datasets" / RUN[0] / RUN[1] / f"seed{RUN[2]}.npz")
    keep = np.isin(data.episode, np.unique(data.episode[data.labels == 0])[:6]) & (data.labels == 0)
    keep |= np.isin(data.episode, np.unique(data.episode[data.labels == 1])[:5]) & (data.labels == 1)
    cfg.dataset_path(*RUN).parent.mkdir(parents=True)
    data.subset(keep).save(cfg.dataset_path(*RUN))
    return cfg


def test_the_stage_writes_the_same_bytes_twice_and_the_table_reads_only_scored_runs(tmp_path):
    cfg = _config(tmp_path / "a")
    first = run_sequence_scores(cfg, *RUN)
    assert sorted(p.name for p in first.iterdir()) == sorted(FILES)
    saved = {name: (first / name).read_bytes() for name in FILES}
    again = run_sequence_scores(cfg, *RUN)
    assert {name: (again / name).read_bytes() for name in FILES} == saved

    metrics, replicates = read_sequence_scores(cfg, [RUN, UNSCORED])  # the baseline has no file: left out
    assert set(metrics[["env", "method", "seed"]].itertuples(index=False, name=None)) == {RUN}
    assert set(metrics.measure) == {"episode_mean", "window_forest"} and set(metrics.ood_set) == {"perturbed", "noise"}
    assert (metrics.n_id == 300).all() and (metrics.n_id_clusters == 3).all()  # 3 of the 6 ID episodes evaluated
    assert len(replicates[(*RUN, "perturbed", "window_forest")]) == cfg.n_bootstrap

    data = StateDataset.load(cfg.dataset_path(*RUN))  # another dataset at the run's path: its scores are stale
    data.subset(np.arange(len(data)) != 0).save(cfg.dataset_path(*RUN))
    with pytest.raises(ValueError, match="sequence_score@HalfCheetah-v5-masksembles-0"):
        read_sequence_scores(cfg, [RUN])


def test_an_atari_run_is_one_error(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["SeaquestNoFrameskip-v4", "masksembles", "0", "--params", str(ROOT / "params.yaml")])
    assert exit_.value.code == 2 and "not a MuJoCo env" in capsys.readouterr().err
