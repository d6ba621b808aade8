"""Transitions simulated from stored states (`paper_lib.ood.transitions`): the s' a real episode gives, a state's
transition whatever it is batched with, and one clear error where an observation does not determine the state."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from paper_lib.agents.envs import make_single_env
from paper_lib.ood.datasets import StateDataset
from paper_lib.ood import transitions
from paper_lib.ood.transitions import EXACT_ENVS, _step_from, transitions_from_states

ROOT = Path(__file__).resolve().parents[2]
DATASET = ROOT / "results" / "paper" / "datasets" / "HalfCheetah-v5" / "baseline" / "seed0.npz"


@pytest.mark.parametrize("env_id", EXACT_ENVS)
def test_a_stored_observation_steps_to_the_episodes_own_next_state(env_id):
    """Set from an observation alone, the simulator steps where the episode's own env stepped (same action)."""
    env, other = make_single_env(env_id), make_single_env(env_id)
    other.reset(seed=1)  # another episode's state and warm start: all of it is replaced
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for t in range(15):
        action = rng.uniform(-1, 1, env.action_space.shape)
        true_next, *_ = env.step(action)
        if t >= 5:  # moving, with contacts
            assert np.allclose(_step_from(other, env_id, obs, action), true_next, rtol=0, atol=1e-9), t
        obs = true_next


def _few_states() -> StateDataset:
    """ID states and perturbed ones under 3 configurations of the committed HalfCheetah dataset."""
    data = StateDataset.load(DATASET)
    ood = np.flatnonzero(data.labels == 1)
    keep = np.concatenate([np.flatnonzero(data.labels == 0)[:6],
                           *[ood[data.config_index[ood] == k][:3] for k in np.unique(data.config_index[ood])[:3]]])
    return data.subset(keep)


def _predict(obs: np.ndarray) -> np.ndarray:
    """A fixed policy: the first action dims of the observation, squashed (no model needed)."""
    return np.tanh(obs[:, :6])


def test_a_states_transition_does_not_depend_on_its_batch_and_each_config_is_its_own_physics():
    data = _few_states()
    whole = transitions_from_states(_predict, data)
    assert whole.actions.shape == (len(data), 6) and whole.next_obs.shape == data.states.shape
    assert np.isfinite(whole.next_obs).all()
    for i in (0, len(data) - 1):  # an ID state and a perturbed one, alone
        alone = transitions_from_states(_predict, data.subset(np.array([i])))
        assert np.array_equal(alone.next_obs[0], whole.next_obs[i]) and np.array_equal(alone.actions[0], whole.actions[i])
    # the same state under the unmodified physics moves elsewhere than under its configuration
    perturbed = len(data) - 1
    as_id = data.subset(np.array([perturbed]))
    as_id.config_index[:] = -1
    assert not np.allclose(transitions_from_states(_predict, as_id).next_obs[0], whole.next_obs[perturbed])


def test_bad_input_is_one_clear_error(monkeypatch):
    data = _few_states()
    data.metadata["env_id"] = "Walker2d-v5"  # its observation clips velocities: not a state
    with pytest.raises(ValueError, match="determine the simulator state"):
        transitions_from_states(_predict, data)
    data.metadata["env_id"] = "Swimmer-v5"  # HalfCheetah's states named as another env's
    with pytest.raises(ValueError, match=r"states have shape \(17,\), an Swimmer-v5 observation \(8,\)"):
        transitions_from_states(lambda obs: np.zeros((len(obs), 2)), data)
    data.metadata["env_id"] = "HalfCheetah-v5"
    monkeypatch.setitem(transitions.OMITTED_POSITIONS, "HalfCheetah-v5", 2)  # a wrong layout: caught before stepping
    with pytest.raises(ValueError, match="reads back differently"):
        transitions_from_states(_predict, data)
