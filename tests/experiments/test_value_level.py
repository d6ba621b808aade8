"""The value-level analysis: -V as an OOD score and value std beyond its trend in V, on small real agents."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch as th

from conftest import TINY
from paper_lib import make_agent, member_outputs, paper_hyperparameters
from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.experiments.value_level import COLUMNS, value_level_reading, value_level_row, value_level_table
from paper_lib.ood.datasets import StateDataset
from paper_lib.scoring.ood_scores import score_run

ENV = "HalfCheetah-v5"


def _run(method: str, tmp_path: Path) -> Checkpoint:
    hp = paper_hyperparameters(ENV)
    hp.update(normalize_obs=False, hidden_sizes=[32, 32])
    model = make_agent("ppo", method, ENV, seed=0, overrides=dict(TINY), hyperparameters=hp)
    return Checkpoint(model=model, config={"env_id": ENV, "method": method}, vecnormalize_path=None, folder=tmp_path)


def _dataset(id_states: np.ndarray, ood_states: np.ndarray) -> StateDataset:
    n_id, n_ood = len(id_states), len(ood_states)
    return StateDataset(states=np.concatenate([id_states, ood_states]), labels=np.r_[np.zeros(n_id), np.ones(n_ood)],
                        source=["id"] * n_id + ["ood"] * n_ood, config_index=np.r_[np.full(n_id, -1), np.zeros(n_ood)],
                        episode=np.r_[np.arange(n_id) // 50, np.zeros(n_ood)], step=np.r_[np.arange(n_id) % 50,
                                                                                           np.arange(n_ood)],
                        configs=["{}"])


@pytest.fixture(scope="module")
def ensemble(tmp_path_factory) -> Checkpoint:
    """An ensemble whose members' values are scaled copies of one value plus a part of their own.

    Member i's value is c_i * f(s) + e_i * g(s) with f > 0 and the e_i summing to 0: V is the mean c times f, and value
    std grows with V (the f part) and varies on its own (the g part), the confound this analysis is about.
    """
    run = _run("ensemble", tmp_path_factory.mktemp("ensemble"))
    head = run.model.policy.mlp_extractor.value_tower[-1]  # MemberLinear: weight (k, d_in, 1), bias (k, 1, 1)
    rng = np.random.default_rng(2)
    shared, own = head.weight.data[0].clone(), th.as_tensor(rng.normal(size=head.weight.shape[1:]), dtype=th.float32)
    with th.no_grad():
        for i, (c, e) in enumerate(zip((1.0, 1.5, 2.0, 2.5), (0.3, -0.3, 0.3, -0.3))):
            head.weight.data[i] = c * shared + e * own
            head.bias.data[i] = c * 3.0
    return run


@pytest.fixture(scope="module")
def low_value_ood(ensemble) -> StateDataset:
    """ID: random states; OOD: the lowest-value fifth of another random pool, so OOD differs from ID only in V."""
    rng = np.random.default_rng(0)
    id_states = rng.normal(size=(1000, 17)).astype(np.float32)
    pool = rng.normal(size=(2500, 17)).astype(np.float32)
    value = member_outputs(ensemble.model.policy, pool).values.mean(axis=0)
    return _dataset(id_states, pool[np.argsort(value)[:500]])


def test_states_that_differ_only_in_value_are_found_by_minus_v_and_not_by_value_std_beyond_its_trend(
        ensemble, low_value_ood):
    row = value_level_row(ensemble, low_value_ood, seed=0)
    assert row["value_auroc"] > 0.85  # low V is the OOD side, so -V ranks them on top
    assert row["n_members"] == 4 and row["n_ood"] == 500 and 0 < row["n_id"] < 1000  # the ID eval half
    raw, beyond = row["value_std_auroc"], row["value_std_beyond_value_auroc"]
    assert abs(row["id_rank_corr"]) > 0.2 and abs(raw - 0.5) > 0.15  # value std moves with V: raw std "detects" them
    assert abs(beyond - 0.5) < 0.1  # ... and says nothing once the ID trend in V is removed
    assert value_level_row(ensemble, low_value_ood, seed=0) == row  # same seed, same numbers


def test_an_mc_run_gets_the_score_stages_value_std_auroc_from_the_same_draws(tmp_path):
    """Table 2 and notebook 13 report one value-std AUROC per run: the same split, scoring seeds and part seeds."""
    run = _run("mc_dropout", tmp_path)
    run.model.learn(total_timesteps=64)  # a (tiny) trained agent, not its initialization
    rng = np.random.default_rng(3)
    data = _dataset(rng.normal(size=(600, 17)).astype(np.float32),
                    (1.5 * rng.normal(size=(300, 17)) + 0.5).astype(np.float32))
    row = value_level_row(run, data, seed=7, n_scoring_seeds=3)
    metrics = score_run(run, data, 7, n_bootstrap=10, n_scoring_seeds=3).metrics.set_index(["ood_set", "measure"])
    scored = metrics.loc[("perturbed", "value_std")]
    assert row["n_scoring_seeds"] == scored.n_scoring_seeds == 3 and scored.auroc_scoring_std > 0  # MC noise exists
    assert (row["n_id"], row["n_ood"]) == (scored.n_id, scored.n_ood)
    assert row["value_std_auroc"] == pytest.approx(scored.auroc, abs=1e-12, rel=0)
    one = value_level_row(run, data, seed=7, n_scoring_seeds=1)  # the first scoring seed alone is another number
    assert one["n_scoring_seeds"] == 1 and one["value_std_auroc"] != row["value_std_auroc"]


def test_a_baseline_has_minus_v_but_no_value_std(tmp_path, low_value_ood):
    row = value_level_row(_run("baseline", tmp_path), low_value_ood, seed=0)
    assert set(row) == set(COLUMNS) and row["n_members"] == 1 and 0 <= row["value_auroc"] <= 1
    assert all(np.isnan(row[c]) for c in ("value_std_auroc", "id_rank_corr", "value_std_beyond_value_auroc"))


def test_a_dataset_without_ood_states_is_one_clear_error(ensemble):
    states = np.random.default_rng(1).normal(size=(100, 17)).astype(np.float32)
    only_id = _dataset(states, states[:0])
    with pytest.raises(ValueError, match="0 OOD states.*collect the run's dataset again"):
        value_level_row(ensemble, only_id, seed=0)


def test_table_means_seeds_and_reading_names_the_methods_the_trend_moves():
    rows = pd.DataFrame([
        {"env": ENV, "method": "baseline", "seed": 0, "value_auroc": 0.94, "value_std_auroc": np.nan,
         "value_std_beyond_value_auroc": np.nan, "id_rank_corr": np.nan},
        *[{"env": ENV, "method": "mc_dropconnect", "seed": s, "value_auroc": 0.9, "value_std_auroc": 0.2 + 0.1 * s,
           "value_std_beyond_value_auroc": 0.5, "id_rank_corr": 0.3} for s in (0, 1)],
        {"env": ENV, "method": "masksembles", "seed": 0, "value_auroc": 0.8, "value_std_auroc": 0.9,
         "value_std_beyond_value_auroc": 0.85, "id_rank_corr": -0.4}])
    table = value_level_table(rows)
    dropconnect = table.set_index("method").loc["mc_dropconnect"]
    assert dropconnect.value_std_auroc == pytest.approx(0.25) and dropconnect.seeds == 2
    (line,) = value_level_reading(table)
    assert "-V alone reaches AUROC 0.80-0.94 (best: baseline 0.94), the best value std masksembles 0.90" in line
    assert "mc_dropconnect 0.25 -> 0.50 (ID rank corr. +0.30)" in line and "masksembles 0.90 ->" not in line
