"""ID / OOD state collection with real envs and tiny real agents: protocol, seeding, action mode, files."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from conftest import TINY
from paper_lib import make_agent, paper_hyperparameters
from paper_lib.ood import collect
from paper_lib.ood.atari import AtariOODConfig, sample_atari_config
from paper_lib.ood.collect import (
    MAIN_TEXT_PROTOCOL,
    ActionMode,
    collect_atari_ood_states,
    collect_id_states,
    collect_mujoco_ood_states,
    noise_ood_states,
    pixel_ood_states,
)
from paper_lib.ood.datasets import StateDataset, concat
from paper_lib.ood.mujoco import PerturbationConfig, UnstablePerturbationWarning, make_perturbed_env
from paper_lib.scoring.ood_scores import score_dataset

ENV = "HalfCheetah-v5"
SAMPLED = ActionMode(deterministic=False)
# Short episodes so that a few dozen states span several episodes (and configurations).
SHORT = {"max_episode_steps": 20, "skip_first": 5}
#: These tests collect raw observations; the normalized path (Walker2d) has a test of its own below.
RAW_HP = {**paper_hyperparameters(ENV), "normalize_obs": False}


@pytest.fixture(scope="module")
def cheetah():
    model = make_agent("ppo", "masksembles", ENV, seed=0, overrides=dict(TINY), hyperparameters=RAW_HP)
    model.learn(128)
    return model


@pytest.fixture(scope="module")
def id_states(cheetah) -> StateDataset:
    return collect_id_states(cheetah, ENV, 40, action_mode=SAMPLED, seed=0, **SHORT)


@pytest.fixture(scope="module")
def ood_states(cheetah) -> StateDataset:
    return collect_mujoco_ood_states(cheetah, ENV, 40, action_mode=SAMPLED, seed=0, **SHORT)


def test_id_states_follow_the_protocol(id_states):
    assert len(id_states) == 40 and id_states.states.shape == (40, 17)
    assert (id_states.labels == 0).all() and set(id_states.source) == {"id"}
    assert (id_states.config_index == -1).all() and id_states.config_json(0) is None
    assert id_states.step.min() >= 5 and id_states.step.max() < 20
    # 15 states per episode (steps 5..19), in order; the last episode stops at n_states.
    np.testing.assert_array_equal(id_states.episode, np.repeat([0, 1, 2], [15, 15, 10]))
    np.testing.assert_array_equal(id_states.step[:15], np.arange(5, 20))
    assert id_states.metadata["protocol"] == {"name": "id", "n_states": 40, "max_episode_steps": 20, "skip_first": 5}


def test_ood_states_carry_a_new_config_per_episode(ood_states):
    assert len(ood_states) == 40 and (ood_states.labels == 1).all()
    assert ood_states.step.min() >= 5 and np.isfinite(ood_states.states).all()
    episodes = np.unique(ood_states.episode)
    assert len(episodes) == 3 and len(ood_states.configs) == 3 == len(set(ood_states.configs))
    for e in episodes:  # one configuration per episode, a different one for every episode
        assert len(np.unique(ood_states.config_index[ood_states.episode == e])) == 1
    assert len(np.unique(ood_states.config_index)) == 3
    for i in range(len(ood_states)):
        text = ood_states.config_json(i)
        config = PerturbationConfig.from_json(text)
        assert config.to_json() == text and ood_states.source[i] == "+".join(config.kinds)
    assert ood_states.metadata["protocol"]["name"] == "appendix"


def test_same_seed_same_states(cheetah, ood_states):
    again = collect_mujoco_ood_states(cheetah, ENV, 40, action_mode=SAMPLED, seed=0, **SHORT)
    assert again.equals(ood_states)
    other = collect_mujoco_ood_states(cheetah, ENV, 40, action_mode=SAMPLED, seed=1, **SHORT)
    assert not np.array_equal(other.states, ood_states.states) and other.configs != ood_states.configs


def test_main_text_variant_gives_configs_times_steps(cheetah):
    assert MAIN_TEXT_PROTOCOL == {"configs": 50, "steps_per_config": 100}
    data = collect_mujoco_ood_states(cheetah, ENV, action_mode=SAMPLED, seed=0, configs=3, steps_per_config=25,
                                     **SHORT)
    assert len(data) == 75 and len(data.configs) == 3
    # 25 states per configuration need two 15-state episodes in the same configuration.
    np.testing.assert_array_equal(np.bincount(data.config_index), [25, 25, 25])
    assert len(np.unique(data.episode)) == 6 and data.step.min() >= 5
    assert data.metadata["protocol"]["name"] == "main"
    with pytest.raises(ValueError, match="configs x steps_per_config"):
        collect_mujoco_ood_states(cheetah, ENV, 10, action_mode=SAMPLED, seed=0, configs=3, steps_per_config=25)
    with pytest.raises(ValueError, match="give both"):
        collect_mujoco_ood_states(cheetah, ENV, action_mode=SAMPLED, seed=0, configs=3)


def test_main_text_protocol_is_the_default_and_id_states_follow_it(cheetah):
    from paper_lib.ood.collect import ID_MAIN_PROTOCOL, _protocol

    assert _protocol(None, None, None) == (5000, 100, "main")
    assert _protocol(None, None, None, ID_MAIN_PROTOCOL) == (2000, 100, "main")
    assert _protocol(300, None, None) == (300, None, "appendix")
    data = collect_id_states(cheetah, ENV, action_mode=SAMPLED, seed=0, episodes=3, steps_per_episode=20, **SHORT)
    # 20 states per run need two 15-state episodes of the same env seed: 3 runs, 6 episodes
    assert len(data) == 60 and len(np.unique(data.episode)) == 6 and data.step.min() >= 5
    assert data.metadata["protocol"] == {"name": "id_main", "n_states": 60, "max_episode_steps": 20, "skip_first": 5,
                                         "episodes": 3, "steps_per_episode": 20}
    with pytest.raises(ValueError, match="give both"):
        collect_id_states(cheetah, ENV, action_mode=SAMPLED, seed=0, episodes=3)


def test_scoring_is_seeded(cheetah, id_states):
    mc = make_agent("ppo", "mc_dropconnect", ENV, seed=0, overrides=dict(TINY), hyperparameters=RAW_HP)
    a, b = score_dataset(mc, id_states), score_dataset(mc, id_states)
    assert a.equals(b)
    assert not np.allclose(score_dataset(mc, id_states, seed=1)["value_std"], a["value_std"])


def test_action_mode_is_applied_and_recorded(cheetah):
    runs = {}
    for member in (0, 1):
        mode = ActionMode(deterministic=True, inference="single", member=member)
        runs[member] = collect_id_states(cheetah, ENV, 10, action_mode=mode, seed=0, **SHORT)
        assert cheetah.policy.inference == ("single", member)
        assert runs[member].metadata["action_mode"] == {"deterministic": True, "inference": "single", "member": member}
        assert runs[member].metadata["policy"] == "members"
        assert runs[member].metadata["model"] == {"algo": "ppo", "method": "masksembles", "env_id": ENV, "seed": 0,
                                                  "n_members": 4}
    # Same env seed, different acting member: the trajectories part after the first action.
    assert not np.array_equal(runs[0].states, runs[1].states)
    cheetah.policy.set_inference("average")

    baseline = make_agent("ppo", "baseline", ENV, seed=0, overrides=dict(TINY), hyperparameters=RAW_HP)
    data = collect_id_states(baseline, ENV, 5, action_mode=ActionMode(False, "single"), seed=0, **SHORT)
    assert data.metadata["policy"] == "baseline"
    with pytest.raises(ValueError, match="has no members"):
        collect_id_states(baseline, ENV, 5, action_mode=ActionMode(False, "single", member=1), seed=0)


@pytest.mark.parametrize("kwargs, match", [
    ({"deterministic": "yes"}, "deterministic"),
    ({"deterministic": True, "inference": "mean"}, "inference"),
    ({"deterministic": True, "inference": "vote", "member": 1}, "only applies"),
    ({"deterministic": True, "inference": "single", "member": -1}, "member index"),
])
def test_bad_action_modes(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ActionMode(**kwargs)


class _FaultAt(gym.Wrapper):
    """Fault injection: a real env whose observations turn NaN (``"nan"``) or whose every episode
    terminates (``"end"``) at step ``at``."""

    def __init__(self, env: gym.Env, fault: str, at: int):
        super().__init__(env)
        self.fault, self.at, self.t = fault, at, 0

    def reset(self, **kwargs):
        self.t = 0
        return self.env.reset(**kwargs)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.t += 1
        if self.t >= self.at and self.fault == "nan":
            obs = np.full_like(obs, np.nan)
        return obs, reward, terminated or (self.t >= self.at and self.fault == "end"), truncated, info


def _first_config_faulty(monkeypatch, fault: str, at: int) -> list[PerturbationConfig]:
    """Make the first configuration drawn faulty; returns every configuration drawn, in order."""
    made: list[PerturbationConfig] = []

    def make(config):
        made.append(config)
        env = make_perturbed_env(config)
        return _FaultAt(env, fault, at) if len(made) == 1 else env

    monkeypatch.setattr(collect, "make_perturbed_env", make)
    return made


def test_unstable_configuration_is_reported_discarded_and_resampled(cheetah, monkeypatch):
    made = _first_config_faulty(monkeypatch, "nan", at=12)
    with pytest.warns(UnstablePerturbationWarning, match="non-finite") as record:
        data = collect_mujoco_ood_states(cheetah, ENV, 30, action_mode=SAMPLED, seed=0, **SHORT)
    assert made[0].to_json() in str(record[0].message)
    assert len(data) == 30 and np.isfinite(data.states).all()
    assert made[0].to_json() not in data.configs and data.metadata["n_rejected_configs"] == 1
    assert data.configs == [c.to_json() for c in made[1:]]


def test_configuration_whose_episodes_all_end_before_skip_first_is_rejected(cheetah, monkeypatch):
    """Main protocol: a configuration that ends every episode at once is redrawn, not retried forever."""
    made = _first_config_faulty(monkeypatch, "end", at=2)
    monkeypatch.setattr(collect, "MAX_EMPTY_PER_CONFIG", 5)
    with pytest.warns(UnstablePerturbationWarning, match="5 episodes in a row ended before skip_first=5") as record:
        data = collect_mujoco_ood_states(cheetah, ENV, action_mode=SAMPLED, seed=0, configs=2, steps_per_config=10,
                                         **SHORT)
    assert made[0].to_json() in str(record[0].message)
    assert len(data) == 20 and data.metadata["n_rejected_configs"] == 1
    assert data.configs == [c.to_json() for c in made[1:]]


def test_episodes_shorter_than_skip_first_leave_no_trace(monkeypatch):
    """An untrained CartPole agent drops the pole within ~10-40 steps: many episodes give no states."""
    model = make_agent("ppo", "ensemble", "CartPole-v1", seed=0, overrides={"n_steps": 16, "batch_size": 32})
    data = collect_id_states(model, "CartPole-v1", 60, action_mode=SAMPLED, seed=0, skip_first=20,
                             max_episode_steps=200)
    assert len(data) == 60 and data.step.min() >= 20
    np.testing.assert_array_equal(np.unique(data.episode), np.arange(data.metadata["n_episodes"]))
    frame = score_dataset(model, data)  # discrete actions: the two extra measures
    assert {"max_prob", "entropy", "value_std"} <= set(frame.columns)
    monkeypatch.setattr(collect, "MAX_EMPTY_IN_A_ROW", 3)
    with pytest.raises(RuntimeError, match="ended before skip_first"):
        collect_id_states(model, "CartPole-v1", 10, action_mode=SAMPLED, seed=0, skip_first=499,
                          max_episode_steps=500)


def test_save_load_round_trip_and_file_errors(id_states, ood_states, tmp_path):
    both = concat(id_states, ood_states)
    path = both.save(tmp_path / "states.npz")
    loaded = StateDataset.load(path)
    assert loaded.equals(both) and loaded.states.dtype == both.states.dtype
    assert [loaded.config_json(i) for i in range(len(loaded))] == [both.config_json(i) for i in range(len(both))]
    with pytest.raises(FileNotFoundError, match="run the collection"):
        StateDataset.load(tmp_path / "missing.npz")
    (tmp_path / "broken.npz").write_bytes(path.read_bytes()[:200])
    with pytest.raises(ValueError, match="damaged or was written by something else: run the collection that writes it again"):
        StateDataset.load(tmp_path / "broken.npz")


def test_concat_subset_and_selection(id_states, ood_states):
    both = concat(id_states, ood_states)
    assert len(both) == 80 and both.configs == ood_states.configs
    for name in ("states", "labels", "source", "config_index", "episode", "step"):
        np.testing.assert_array_equal(getattr(both.id_only(), name), getattr(id_states, name))
        np.testing.assert_array_equal(getattr(both.ood_only(), name), getattr(ood_states, name))
    assert [both.ood_only().config_json(i) for i in range(40)] == [ood_states.config_json(i) for i in range(40)]
    # Configs of the second dataset are remapped behind the first one's.
    twice = concat(ood_states, ood_states.subset(np.arange(20, 40)))
    assert twice.configs == ood_states.configs
    assert [twice.config_json(i) for i in range(40, 60)] == [ood_states.config_json(i) for i in range(20, 40)]
    assert both.metadata["env_id"] == ENV and len(both.metadata["parts"]) == 2
    other_mode = StateDataset(**{**{k: getattr(id_states, k) for k in ("states", "labels", "source", "config_index",
                                                                       "episode", "step")},
                                 "metadata": {**id_states.metadata, "action_mode": {"deterministic": True}}})
    with pytest.raises(ValueError, match="different action_mode"):
        concat(other_mode, ood_states)


def _states_in(configs: list[str], per_config: int = 2) -> StateDataset:
    """OOD states, `per_config` per configuration, each configuration one episode (as the collectors keep them)."""
    n = per_config * len(configs)
    index = np.repeat(np.arange(len(configs)), per_config)
    return StateDataset(states=np.zeros((n, 3)), labels=np.ones(n), source=["s"] * n, config_index=index,
                        episode=index, step=np.tile(np.arange(per_config), len(configs)), configs=configs)


def test_identical_configurations_are_one_condition():
    """The generators' configurations differ by their env seed alone when they draw the same maze or physics:
    one condition, numbered once; other parameters make another; states of the unmodified env have none."""
    maze = [AtariOODConfig("MsPacman", "maze", v, seed=s).to_json() for v, s in ((2, 11), (3, 12), (2, 13), (2, 14))]
    data = _states_in(maze)
    np.testing.assert_array_equal(data.condition_index(), [0, 0, 1, 1, 0, 0, 0, 0])
    assert data.n_conditions == 2 and data.subset(data.config_index == 1).n_conditions == 1
    assert "8 OOD, 2 distinct OOD conditions" in repr(data)
    physics = [PerturbationConfig(ENV, gravity=(0.0, 0.0, -2.0), seed=s).to_json() for s in (1, 2)]
    physics.append(PerturbationConfig(ENV, gravity=(0.0, 0.0, -3.0), seed=1).to_json())
    assert _states_in(physics).n_conditions == 2
    # concat remaps configs; conditions follow; the unmodified env's states (config -1) count as none
    both = concat(_states_in(maze), _states_in(physics))
    assert both.n_conditions == 4 and len(both.configs) == 7
    ids = StateDataset(states=np.zeros((2, 3)), labels=[0, 0], source=["id"] * 2, config_index=[-1, -1],
                       episode=[0, 1], step=[0, 0])
    assert ids.n_conditions == 0 and (ids.condition_index() == -1).all()
    # a real generator: 50 MsPacman draws are its 3 mazes
    rng = np.random.default_rng(0)
    assert _states_in([sample_atari_config("MsPacman", rng).to_json() for _ in range(50)], 1).n_conditions == 3


def test_bad_inputs_raise_clear_errors(cheetah):
    for n in (0, -5, 2.5):
        with pytest.raises(ValueError, match="n_states"):
            collect_id_states(cheetah, ENV, n, action_mode=SAMPLED, seed=0)
    with pytest.raises(ValueError, match="unknown env id"):
        collect_id_states(cheetah, "HalfCheetah-v9", 10, action_mode=SAMPLED, seed=0)
    with pytest.raises(ValueError, match="unknown MuJoCo env"):
        collect_mujoco_ood_states(cheetah, "Hopper-v5", 10, action_mode=SAMPLED, seed=0)
    with pytest.raises(ValueError, match="trained on HalfCheetah-v5"):
        collect_mujoco_ood_states(cheetah, "Ant-v5", 10, action_mode=SAMPLED, seed=0)
    with pytest.raises(ValueError, match="skip_first"):
        collect_id_states(cheetah, ENV, 10, action_mode=SAMPLED, seed=0, skip_first=20, max_episode_steps=20)
    with pytest.raises(TypeError, match="ActionMode"):
        collect_id_states(cheetah, ENV, 10, action_mode="vote", seed=0)


def test_score_dataset_has_every_measure(cheetah, id_states, ood_states):
    data = concat(id_states, noise_ood_states(id_states, np.random.default_rng(0)))
    assert set(data.source) == {"id", "noise"}
    frame = score_dataset(cheetah, concat(data, ood_states))
    assert len(frame) == 120
    assert {"value_std", "policy_std", "policy_js", "label", "source", "episode", "step"} <= set(frame.columns)
    assert np.isfinite(frame[["value_std", "policy_std", "policy_js"]].to_numpy()).all()
    np.testing.assert_array_equal(frame["label"], np.repeat([0, 1, 1], 40))


def test_vecnormalize_policy_acts_on_normalized_obs(tmp_path):
    walker = make_agent("ppo", "mc_dropout", "Walker2d-v5", seed=0, overrides=dict(TINY))
    walker.learn(128)
    vecnormalize = walker.get_vec_normalize_env()
    with pytest.raises(ValueError, match="pass vecnormalize"):
        collect_id_states(walker, "Walker2d-v5", 10, action_mode=SAMPLED, seed=0)
    mean_before = vecnormalize.obs_rms.mean.copy()
    data = collect_mujoco_ood_states(walker, "Walker2d-v5", 20, action_mode=SAMPLED, seed=0,
                                     vecnormalize=vecnormalize, **SHORT)
    np.testing.assert_array_equal(vecnormalize.obs_rms.mean, mean_before)  # statistics never move
    np.testing.assert_allclose(data.policy_obs, vecnormalize.normalize_obs(data.states))
    assert not np.allclose(data.policy_obs, data.states) and data.metadata["vecnormalize"] is True
    assert StateDataset.load(data.save(tmp_path / "walker.npz")).equals(data)
    frame = score_dataset(walker, data)
    assert len(frame) == 20 and np.isfinite(frame["value_std"]).all()


def test_atari_ood_states():
    game = "SeaquestNoFrameskip-v4"
    model = make_agent("ppo", "masksembles", game, seed=0, n_envs=4, overrides=dict(TINY))
    model.learn(64)
    mode = ActionMode(deterministic=False, inference="vote")
    ood = collect_atari_ood_states(model, game, 20, action_mode=mode, seed=0, **SHORT)
    assert ood.states.shape == (20, 84, 84, 4) and ood.states.dtype == np.uint8 and (ood.labels == 1).all()
    for i in range(len(ood)):
        assert AtariOODConfig.from_json(ood.config_json(i)).to_json() == ood.config_json(i)
    assert json.loads(ood.configs[0])["source"] == ood.source[0] == "level"
    id_data = collect_id_states(model, game, 10, action_mode=mode, seed=0, **SHORT)
    pixels = pixel_ood_states(id_data, ["black", "mask"], np.random.default_rng(0))
    assert sorted(set(pixels.source)) == ["pixels:black", "pixels:mask"] and len(pixels) == 20
    assert (pixels.states[pixels.source == "pixels:black"] == 0).all()
    frame = score_dataset(model, concat(concat(id_data, ood), pixels))
    assert len(frame) == 50 and {"max_prob", "entropy", "value_std"} <= set(frame.columns)
