"""Transitions from stored states: what a dynamics detector (PEDM) scores on Table 2's states (issue 69 item 1).

The main datasets keep each state's observation, its physics and its episode, not the action the agent sampled there,
so PEDM, which scores how surprising s' is given (s, a), cannot read them as they are. Recollecting them with the
actions would redraw every state (MuJoCo differs in the last bits across CPUs and the episodes are chaotic), and every
committed score and verdict with them. Instead each stored state becomes a transition by one step of simulation:

- the env is set to the state its observation describes: positions the observation leaves out (the root's x, and
  y for Swimmer and Ant) are 0, as the dynamics of a flat floor and a uniform fluid do not depend on them. Walker2d
  is left out (`EXACT_ENVS`): its observation clips velocities at +-10, so it does not determine the state;
- under the state's own physics: its OOD configuration (`config_json`), the unmodified env for ID and noise states;
- the agent acts on it deterministically (PEDM's protocol plays deterministic actions, and its model is fit on them),
  and one env step gives s'. The solver's warm start is cleared first, so a state's transition does not depend on
  which state was stepped before it.

So (s, a, s') is a true transition of the simulator from the state of the stored observation (it reads back bit for
bit, checked for every state), though its action is not the one that led on in the stored episode. Simulation, so computed once
and committed (the `pedm` stage), never at rebuild.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch as th

from paper_lib.agents.envs import make_single_env
from paper_lib.ood.datasets import StateDataset
from paper_lib.ood.mujoco import PerturbationConfig, make_perturbed_env

#: Positions each env's observation leaves out (gymnasium v5, ``exclude_current_positions_from_observation``).
OMITTED_POSITIONS = {"HalfCheetah-v5": 1, "Walker2d-v5": 1, "Swimmer-v5": 2, "Ant-v5": 2}
#: The envs whose observation determines the simulator's state. Walker2d's clips its velocities at +-10 (31% of
#: baseline seed 0's ID states have one there): the state it is set to would move slower than the one observed.
EXACT_ENVS = ("HalfCheetah-v5", "Swimmer-v5", "Ant-v5")


@dataclass(frozen=True)
class Transitions:
    actions: np.ndarray  # (n, action dims) float64, what the agent chose (clipped to the action space)
    next_obs: np.ndarray  # (n, obs dims) float64, the raw observation after one env step


def state_from_observation(env: gym.Env, env_id: str, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, qvel) whose observation is `obs` (the omitted positions at 0)."""
    model = env.unwrapped.model
    n_pos = model.nq - OMITTED_POSITIONS[env_id]
    obs = np.asarray(obs, dtype=np.float64)
    if obs.ndim != 1 or len(obs) < n_pos + model.nv:
        raise ValueError(f"an {env_id} observation has at least {n_pos + model.nv} values (positions, velocities), "
                         f"got shape {obs.shape}: pass the dataset's raw states, not another env's")
    qpos = np.concatenate([np.zeros(OMITTED_POSITIONS[env_id]), obs[:n_pos]])
    return qpos, obs[n_pos:n_pos + model.nv].copy()


def _step_from(env: gym.Env, env_id: str, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
    """Set `env` to the state of `obs`, check that it reads back as `obs`, and step it once with `action`."""
    base = env.unwrapped
    qpos, qvel = state_from_observation(env, env_id, obs)
    base.data.qacc_warmstart[:] = 0.0
    base.set_state(qpos, qvel)
    n = len(qpos) - OMITTED_POSITIONS[env_id] + len(qvel)
    seen = base._get_obs()[:n]  # Ant's contact forces after them come from the step, not from set_state
    if not np.array_equal(seen, obs[:n]):
        raise ValueError(f"the {env_id} state set from a stored observation reads back differently (max difference "
                         f"{np.max(np.abs(seen - obs[:n])):.3g}): the dataset's states are not this env's raw "
                         "observations; score a dataset collected by `paper_lib.ood.collect`")
    next_obs, *_ = env.step(action)
    return np.asarray(next_obs, dtype=np.float64)


def _env_for(env_id: str, config_json: str | None) -> gym.Env:
    env = make_single_env(env_id) if config_json is None else make_perturbed_env(PerturbationConfig.from_json(config_json))
    env.reset(seed=0)  # the wrappers' order checks; the state is set before every step
    return env


def transitions_from_states(predict: Callable[[np.ndarray], np.ndarray], data: StateDataset,
                            policy_obs: Callable[[np.ndarray], np.ndarray] | None = None,
                            torch_seed: int = 0) -> Transitions:
    """One transition from each state of `data` (a MuJoCo dataset's raw states), under the state's own physics.

    ``predict`` maps a batch of what the policy reads to deterministic actions (a model's
    ``lambda o: model.predict(o, deterministic=True)[0]``); ``policy_obs`` maps raw states to that (the run's
    frozen normalizer), None for raw. ``torch_seed`` seeds the draws of an MC method's members.
    """
    env_id = data.metadata.get("env_id")
    if env_id not in EXACT_ENVS:
        raise ValueError(f"transitions are simulated from the stored states of {EXACT_ENVS}, whose observations "
                         f"determine the simulator state; the dataset is of {env_id!r}")
    states = np.asarray(data.states, dtype=np.float64)
    th.manual_seed(torch_seed)
    actions = np.asarray(predict(states if policy_obs is None else policy_obs(states)), dtype=np.float64)
    if actions.ndim != 2 or len(actions) != len(states):
        raise ValueError(f"predict must give one action row per state ({len(states)}), got shape {actions.shape}")
    next_obs = np.empty_like(states)
    for k in np.unique(data.config_index):  # one env per physics: geometry edits build a model
        rows = np.flatnonzero(data.config_index == k)
        env = _env_for(env_id, data.config_json(rows[0]))
        if states.shape[1:] != env.observation_space.shape:
            env.close()
            raise ValueError(f"the dataset's states have shape {states.shape[1:]}, an {env_id} observation "
                             f"{env.observation_space.shape}: its metadata names another env than its states are of")
        try:
            actions[rows] = np.clip(actions[rows], env.action_space.low, env.action_space.high)  # as SB3's predict
            for i in rows:
                next_obs[i] = _step_from(env, env_id, states[i], actions[i])
        finally:
            env.close()
    return Transitions(actions, next_obs)
