"""The OOD-source coverage check: ID rollouts record the source's indicator, and a source they reached is caught.

Berzerk, the weakest default source (RAM 92 counts the rooms entered), with an untrained
Nature-CNN agent: a few seconds of play per collection.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import TINY
from paper_lib import make_agent
from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.ood import collect as collect_module
from paper_lib.ood.atari import AtariOODConfig, make_ood_atari_env
from paper_lib.ood.collect import ActionMode, collect_atari_ood_states, collect_id_states
from paper_lib.ood.coverage import COVERAGE_COLUMNS, FAILED, NOT_CHECKED, PASSED, STALE, source_coverage
from paper_lib.ood.datasets import StateDataset, concat
from paper_lib.pipeline.run_results import read_source_coverage, score_files, score_run_files

GAME = "Berzerk"
ENV = f"{GAME}NoFrameskip-v4"
MODE = ActionMode(deterministic=False)
SHORT = dict(max_episode_steps=30, skip_first=2)


@pytest.fixture(scope="module")
def agent():
    return make_agent("ppo", "baseline", ENV, seed=0, n_envs=2, overrides=dict(TINY))  # untrained: stays in room 1


def collect_id(agent, **kwargs) -> StateDataset:
    return collect_id_states(agent, ENV, seed=1, action_mode=MODE, episodes=2, steps_per_episode=10, **SHORT, **kwargs)


@pytest.fixture(scope="module")
def dataset(agent) -> StateDataset:
    ood = collect_atari_ood_states(agent, ENV, seed=2, action_mode=MODE, configs=2, steps_per_config=10, **SHORT)
    return concat(collect_id(agent), ood)


def test_every_state_records_the_indicator_and_keeps_it_on_disk(dataset, tmp_path):
    assert dataset.metadata["source_indicator"] == {"game": GAME, "source": "level", "read": "RAM 92"}
    indicator, is_id = dataset.source_indicator, dataset.labels == 0
    assert indicator.dtype == np.int16 and set(indicator[is_id].tolist()) <= set(range(1, 10))
    for config in set(dataset.config_index[~is_id].tolist()):
        in_config = np.flatnonzero(dataset.config_index == config)
        value = AtariOODConfig.from_json(dataset.configs[config]).value
        assert indicator[in_config[0]] == value and (indicator[in_config] >= value).all()  # the counter only rises
    assert StateDataset.load(dataset.save(tmp_path / "d.npz")).equals(dataset)


def test_the_check_passes_on_rollouts_that_stay_in_the_first_rooms(dataset):
    row = source_coverage(dataset)
    assert list(row.columns) == list(COVERAGE_COLUMNS) and len(row) == 1
    first = row.iloc[0]
    assert (first.game, first.ood_source, first.indicator, first.ood_values) == (GAME, "level", "RAM 92",
                                                                                  "10;11;12;13;14;15")
    assert first.check == PASSED and first.id_states_at_ood_values == 0 and first.id_share_at_ood_values == 0
    assert first.n_id_states == first.n_id_recorded == 20 and first.id_max < 10 and first.ood_share_at_ood_values > 0
    pd.testing.assert_frame_equal(source_coverage(dataset, GAME), row)  # a function of the dataset alone


def test_id_rollouts_forced_into_an_ood_room_are_caught(agent, dataset, monkeypatch):
    """The check must fail a source whose states the agent reaches: here every ID game starts in room 12."""
    forced = lambda game, seed: make_ood_atari_env(AtariOODConfig(game, "level", 12, seed=seed))
    monkeypatch.setattr(collect_module, "make_atari_env_single", forced)
    reached = concat(collect_id(agent), dataset.ood_only())
    row = source_coverage(reached).iloc[0]
    assert row.check == FAILED and row.id_states_at_ood_values > 0 and "12" in row.id_values.split(";")


def test_datasets_without_indicators_still_load_and_say_so(dataset, tmp_path):
    old = dataclasses.replace(dataset, source_indicator=None, metadata={
        **dataset.metadata, "parts": [{k: v for k, v in p.items() if k != "source_indicator"}
                                      for p in dataset.metadata["parts"]]})
    loaded = StateDataset.load(old.save(tmp_path / "old.npz"))
    assert loaded.source_indicator is None and np.array_equal(loaded.states, dataset.states)
    row = source_coverage(loaded).iloc[0]
    assert row.check == NOT_CHECKED and row.n_id_recorded == 0 and pd.isna(row.id_max)


def test_a_dataset_that_read_another_indicator_is_stale_not_passed(dataset):
    """A dataset collected before the source's indicator changed (Seaquest: RAM 61 -> 60) must not pass."""
    def reread(part: dict) -> dict:
        if part.get("kind") != "id":
            return part
        return {**part, "source_indicator": {**part["source_indicator"], "read": "RAM 93"}}
    older = dataclasses.replace(dataset, metadata={**dataset.metadata,
                                                   "parts": [reread(p) for p in dataset.metadata["parts"]]})
    row = source_coverage(older).iloc[0]
    assert row.check == STALE and row.indicator == "RAM 93" and row.id_states_at_ood_values == 0


def test_bad_inputs_raise_one_clear_error(agent, dataset):
    with pytest.raises(ValueError, match="collect the ID states with indicator_source='level'"):
        source_coverage(concat(collect_id(agent, indicator_source="mode"), dataset.ood_only()))
    with pytest.raises(ValueError, match="pass its own game"):
        source_coverage(dataset, "Seaquest")
    with pytest.raises(ValueError, match="Unknown OOD source 'rooms'"):
        collect_id(agent, indicator_source="rooms")
    with pytest.raises(ValueError, match="Atari games only"):
        collect_id_states(agent, "HalfCheetah-v5", 10, action_mode=MODE, seed=0, indicator_source="level")
    mujoco = dataclasses.replace(dataset, metadata={"env_id": "HalfCheetah-v5"})
    with pytest.raises(ValueError, match="Atari datasets only"):
        source_coverage(mujoco)
    with pytest.raises(TypeError, match="StateDataset"):
        source_coverage(dataset.states)


@dataclasses.dataclass
class _Profile:
    """The part of RunConfig the score stage reads."""

    results: Path
    n_bootstrap: int = 10
    n_scoring_seeds: int = 1

    def checkpoint_dir(self, env_id: str, method: str, seed: int) -> Path:
        return self.results / "checkpoints" / env_id / method / f"seed{seed}"

    def dataset_path(self, env_id: str, method: str, seed: int) -> Path:
        return self.results / "datasets" / env_id / method / f"seed{seed}.npz"


def test_the_score_stage_writes_the_check_of_atari_runs(agent, dataset, tmp_path, monkeypatch):
    cfg = _Profile(tmp_path)
    dataset.save(cfg.dataset_path(ENV, "baseline", 0))
    checkpoint = Checkpoint(agent, agent.paper_lib_config, None, tmp_path)
    monkeypatch.setattr("paper_lib.agents.checkpoints.load_checkpoint", lambda *args: checkpoint)
    cfg.checkpoint_dir(ENV, "baseline", 0).mkdir(parents=True)
    agent.save(cfg.checkpoint_dir(ENV, "baseline", 0) / "model.zip")  # its digest goes into provenance.json
    folder = score_run_files(cfg, ENV, "baseline", 0)
    assert sorted(p.name for p in folder.iterdir()) == sorted([*score_files(ENV), "provenance.json"])
    table = read_source_coverage(cfg, [(ENV, "baseline", 0), ("HalfCheetah-v5", "baseline", 0)])
    assert len(table) == 1 and table.check[0] == PASSED and (table.env[0], table.seed[0]) == (ENV, 0)
    assert "source_coverage.csv" not in score_files("HalfCheetah-v5")
    with pytest.raises(FileNotFoundError, match="score those runs again"):
        read_source_coverage(cfg, [(ENV, "baseline", 1)])


def test_play_coverage_checks_whole_games_against_the_sources_values():
    from paper_lib.ood.play_coverage import PLAY_FAILED, PLAY_NOT_RECORDED, PLAY_PASSED, play_coverage

    rows = pd.DataFrame({
        "env": ["BerzerkNoFrameskip-v4"] * 3 + ["SeaquestNoFrameskip-v4"] * 2 + ["HalfCheetah-v5"],
        "method": "baseline", "seed": [0, 0, 1, 0, 0, 0],
        # Berzerk's source sets rooms 10-15; Seaquest's levels 1-16
        "source_indicator_max": [4, 7, 12, 0, 0, np.nan]})
    out = play_coverage(rows).set_index(["env", "seed"])
    assert ("HalfCheetah-v5", 0) not in out.index  # not an Atari run
    assert out.loc[("BerzerkNoFrameskip-v4", 0), "play_check"] == PLAY_PASSED
    assert out.loc[("BerzerkNoFrameskip-v4", 0), "play_max"] == 7
    assert out.loc[("BerzerkNoFrameskip-v4", 1), "play_check"] == PLAY_FAILED
    assert out.loc[("BerzerkNoFrameskip-v4", 1), "games_at_ood_values"] == 1
    assert out.loc[("SeaquestNoFrameskip-v4", 0), "play_check"] == PLAY_PASSED
    old = play_coverage(rows.drop(columns="source_indicator_max"))  # evaluated before the column existed
    assert set(old["play_check"]) == {PLAY_NOT_RECORDED}
    with pytest.raises(ValueError, match="missing \\['seed'\\]"):
        play_coverage(rows.drop(columns="seed"))
