"""A file of one run at another run's path is refused, never read as that run's (issue 41: nothing mixed up)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.run_results import check_dataset_identity, evaluation_path, read_evaluations

REPO = Path(__file__).resolve().parents[1]


def _episodes(env: str, method: str, seed: int) -> pd.DataFrame:
    return pd.DataFrame({"inference": "single", "deterministic": [True, False], "member": np.nan, "reward": [1.0, 2.0],
                         "length": 10, "env": env, "method": method, "seed": seed})


def test_another_seeds_evaluation_at_a_runs_path_is_refused_naming_both(tmp_path):
    cfg = dataclasses.replace(load_run_config(REPO / "params.yaml"), profile="tiny", root=tmp_path)
    for seed, rows_of in ((0, 1), (1, 1)):  # seed 1's episodes copied to seed 0's path
        path = evaluation_path(cfg, "HalfCheetah-v5", "baseline", seed)
        path.parent.mkdir(parents=True, exist_ok=True)
        _episodes("HalfCheetah-v5", "baseline", rows_of).to_csv(path, index=False)
    assert len(read_evaluations(cfg, [("HalfCheetah-v5", "baseline", 1)])) == 2
    with pytest.raises(ValueError, match=r"seed0\.csv belongs to HalfCheetah-v5 baseline seed 1, not to HalfCheetah-v5 "
                                         r"baseline seed 0 whose path it sits at"):
        read_evaluations(cfg, [("HalfCheetah-v5", "baseline", 0), ("HalfCheetah-v5", "baseline", 1)])


def test_a_committed_dataset_is_refused_at_another_methods_path():
    """Swimmer Masksembles' states scored as Swimmer's baseline (the issue's case) stop at the door."""
    path = REPO / "results/paper/datasets/Swimmer-v5/masksembles/seed0.npz"
    if not path.is_file():
        pytest.skip("the committed Swimmer dataset is not in this checkout")
    with np.load(path, allow_pickle=False) as data:
        metadata = json.loads(str(data["metadata"]))
    check_dataset_identity(metadata, path, "Swimmer-v5", "masksembles", 0)  # its own path: fine
    with pytest.raises(ValueError, match=r"belongs to Swimmer-v5 masksembles seed 0, not to Swimmer-v5 baseline seed 0"):
        check_dataset_identity(metadata, path, "Swimmer-v5", "baseline", 0)
