"""PEDM's protocol on real v5 envs, a few dozen steps: labels flip at the injection, every kind changes the dynamics."""

import numpy as np
import pytest

from paper_lib.agents.envs import MUJOCO_ENVS, make_single_env
from paper_lib.ood.pedm_protocol import (KINDS, SEVERITIES, episode_seeds, make_pedm_env, perturbation_value,
                                         play_pedm_episodes)

STEPS, INJECT = 25, 10


def rollout(env, actions: np.ndarray, seed: int = 3):
    obs, _ = env.reset(seed=seed)
    states, labels = [obs], []
    for a in actions:
        obs, _, terminated, truncated, info = env.step(a)
        states.append(obs)
        labels.append(info.get("ood_label", 0))
        assert not (terminated or truncated)
    return np.array(states), np.array(labels)


def actions_for(env_id: str) -> np.ndarray:
    space = make_single_env(env_id).action_space
    return np.random.default_rng(0).uniform(space.low, space.high, size=(STEPS, *space.shape))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("severity", SEVERITIES)
def test_half_cheetah_every_kind_changes_dynamics_from_the_injection_on(kind, severity):
    actions = actions_for("HalfCheetah-v5")
    base, _ = rollout(make_single_env("HalfCheetah-v5"), actions)
    pert, labels = rollout(make_pedm_env("HalfCheetah-v5", kind, severity, injection_step=INJECT), actions)
    np.testing.assert_array_equal(labels, (np.arange(STEPS) >= INJECT).astype(int))
    np.testing.assert_array_equal(pert[:INJECT + 1], base[:INJECT + 1])  # s_0..s_INJECT come before the change
    assert not np.array_equal(np.diff(pert, axis=0)[INJECT:], np.diff(base, axis=0)[INJECT:])


@pytest.mark.parametrize("env_id", MUJOCO_ENVS)
def test_every_env_gets_the_translated_force_and_mass(env_id):
    actions = actions_for(env_id)[:15]
    base, _ = rollout(make_single_env(env_id), actions)
    for kind in ("force_vector", "bm_factor"):
        env = make_pedm_env(env_id, kind, "severe", injection_step=5)
        pert, labels = rollout(env, actions)
        assert labels[4] == 0 and labels[5] == 1
        np.testing.assert_array_equal(pert[:6], base[:6])
        assert np.abs(pert[7:] - base[7:]).max() > 1e-6
    mass = float(env.unwrapped.model.body_mass.sum()) / 1.5  # bm_factor severe scaled every body by 1.5
    assert perturbation_value(env_id, "force_vector", "severe", mass) == pytest.approx(-15.0 * mass / 14.0)
    env.reset(seed=0)  # a reset restores the nominal masses
    assert float(env.unwrapped.model.body_mass.sum()) == pytest.approx(mass)


def test_random_injection_is_seeded_and_paired_across_kinds():
    steps = {kind: [make_pedm_env("Swimmer-v5", kind).reset(seed=s)[1]["injection_step"] for s in (1, 2, 3)]
             for kind in ("act_noise", "force_vector")}
    assert steps["act_noise"] == steps["force_vector"]
    assert all(2 <= s < 1000 for s in steps["act_noise"])
    assert make_pedm_env("Swimmer-v5", None).reset(seed=1)[1]["injection_step"] == -1


class RandomAgent:
    def __init__(self, space):
        self.space = space

    def predict(self, obs, deterministic=True):
        rng = np.random.default_rng(int(abs(obs).sum() * 1e6) % 2**32)  # a function of the observation only
        return rng.uniform(self.space.low, self.space.high), None


def test_play_records_transitions_reproducibly():
    agent = RandomAgent(make_single_env("HalfCheetah-v5").action_space)
    data = play_pedm_episodes(agent, "HalfCheetah-v5", "act_offset", "severe", n_episodes=2, seed=5, max_steps=12)
    again = play_pedm_episodes(agent, "HalfCheetah-v5", "act_offset", "severe", n_episodes=2, seed=5, max_steps=12)
    for key in data:
        np.testing.assert_array_equal(data[key], again[key])
    assert data["obs"].shape == (24, 17) and data["action"].shape == (24, 6) and data["next_obs"].shape == (24, 17)
    np.testing.assert_array_equal(data["episode"], np.repeat([0, 1], 12))
    np.testing.assert_array_equal(data["next_obs"][:11], data["obs"][1:12])  # s' of step t is s of step t + 1
    np.testing.assert_array_equal(data["label"], (data["step"] >= data["injection_step"]).astype(int))
    assert episode_seeds(5, 2) == episode_seeds(5, 3)[:2]
    ident = play_pedm_episodes(agent, "HalfCheetah-v5", None, n_episodes=1, seed=5, max_steps=5)
    assert ident["label"].sum() == 0 and (ident["injection_step"] == -1).all()


def test_bad_arguments():
    with pytest.raises(ValueError, match="kind"):
        make_pedm_env("HalfCheetah-v5", "gravity")
    with pytest.raises(ValueError, match="severity"):
        make_pedm_env("HalfCheetah-v5", "act_noise", "medium")
    with pytest.raises(ValueError, match="MuJoCo"):
        make_pedm_env("Hopper-v5", "act_noise")
    with pytest.raises(ValueError, match="injection_step"):
        make_pedm_env("HalfCheetah-v5", "act_noise", injection_step=-3)
    with pytest.raises(ValueError, match="n_episodes"):
        play_pedm_episodes(None, "HalfCheetah-v5", "act_noise", n_episodes=0)
