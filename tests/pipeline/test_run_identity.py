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

REPO = Path(__file__).resolve().parents[2]


def _episodes(env: str, method: str, seed: int) -> pd.DataFrame:
    return pd.DataFrame({"inference": "single", "deterministic": [True, False], "member": np.nan, "reward": [1.0, 2.0],
                         "length": 10, "env": env, "method": method, "seed": seed})


def test_another_seeds_evaluation_at_a_runs_path_is_refused_naming_both(tmp_path):
    cfg = dataclasses.replace(load_run_config(REPO / "params.yaml"), profile="tiny", root=tmp_path, eval_episodes=1)
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


# ----------------------------------------------------------------------------- labels against their sources


def _dataset(labels: list[int], sources: list[str]) -> "StateDataset":
    from paper_lib.ood.datasets import StateDataset

    n = len(labels)
    return StateDataset(states=np.random.default_rng(0).normal(size=(n, 17)).astype(np.float32), labels=labels,
                        source=sources, config_index=np.full(n, -1), episode=np.arange(n) // 4, step=np.arange(n) % 4)


def test_a_dataset_file_whose_labels_contradict_their_sources_is_refused_naming_it(tmp_path):
    """An ID state labelled OOD, and an OOD state labelled ID: one error with the file, the count and an example."""
    from paper_lib.ood.datasets import StateDataset

    labels, sources = [0] * 6 + [1] * 6, ["id"] * 6 + ["gravity"] * 6
    StateDataset.load(_dataset(labels, sources).save(tmp_path / "good.npz"))  # agreeing labels load
    labels[7], sources[2] = 1, "id"  # fine: an OOD label on a gravity state; then the mix-ups
    labels[2], labels[9] = 1, 0
    path = _dataset(labels, sources).save(tmp_path / "mixed.npz")
    before = path.read_bytes()
    with pytest.raises(ValueError, match=rf"^{path}: 2 of 12 states have a label that contradicts their source \(e\.g\. "
                                         r"state 2: source 'id' labelled OOD\); ID states, and only they, come from "
                                         r"source 'id': collect the states again"):
        StateDataset.load(path)
    assert path.read_bytes() == before
    only_id_side = _dataset([0] * 6 + [1] * 6, ["id"] * 5 + ["noise"] + ["gravity"] * 6).save(tmp_path / "id_side.npz")
    with pytest.raises(ValueError, match=r"1 of 12 states .* \(e\.g\. state 5: source 'noise' labelled ID\)"):
        StateDataset.load(only_id_side)


def test_scoring_a_dataset_whose_labels_contradict_their_sources_is_refused_before_any_work():
    from paper_lib import make_agent
    from paper_lib.agents.factory import paper_hyperparameters
    from paper_lib.scoring.ood_scores import score_run

    hp = {**paper_hyperparameters("HalfCheetah-v5"), "normalize_obs": False}  # the states are the policy's input
    model = make_agent("ppo", "baseline", "HalfCheetah-v5", 0, overrides={"n_steps": 16, "batch_size": 32},
                       hyperparameters=hp)
    labels, sources = [0] * 80 + [1] * 16, ["id"] * 80 + ["wind"] * 16  # 20 ID episodes: enough to fit the detectors
    assert len(score_run(model, _dataset(labels, sources), 0, 5).metrics) > 0
    labels[90] = 0
    with pytest.raises(ValueError, match=r"^the dataset: 1 of 96 states .* \(e\.g\. state 90: source 'wind' labelled ID\)"):
        score_run(model, _dataset(labels, sources), 0, 5)


def test_every_committed_dataset_labels_exactly_its_id_source_states_id():
    """The rule `check_labels` enforces holds for every dataset the project has collected (read without states)."""
    from types import SimpleNamespace

    from paper_lib.ood.datasets import label_contradictions

    checked = 0
    for path in sorted((REPO / "results").rglob("*.npz")):
        with np.load(path, allow_pickle=False) as f:
            if "labels" not in f.files or "source" not in f.files:
                continue
            data = SimpleNamespace(labels=f["labels"], source=f["source"])
        assert not label_contradictions(data).any(), path
        checked += 1
    if not checked:
        pytest.skip("no committed dataset in this checkout")
