"""Mid-episode physics changes: the default robot until step c, then the same robot state in perturbed physics.

The paper's OOD states come from episodes that are perturbed from their first step; a deployed
agent meets a change while it is running. ``MidEpisodeShift`` runs the default env until
``change_step`` and then continues from the very same joint positions and velocities in a second
env built from a ``paper_lib.ood.mujoco.PerturbationConfig`` (gravity, wind, friction, geometry).
Copying the state into a separately compiled model is what makes geometry possible mid-episode
(longer limbs need a recompiled model); scalar physics goes the same way, so every kind of change
takes one code path. A geometry model lifts its torso so longer legs start above the floor: the
copied state is then the same joint configuration a little higher, and the robot drops onto its
new legs.

Time convention: the action taken at state s_c (the ``change_step``-th call to ``step``, counting
from 0) is simulated in the perturbed physics, so s_{c+1} is the first state it produced, and a
detection delay of d steps means the guard first flagged s_{c+d}.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from paper_lib.agents.envs import make_single_env
from paper_lib.ood.mujoco import PerturbationConfig, is_unstable, make_perturbed_env

_INSTABILITY = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQACC)


class MidEpisodeShift(gym.Env):
    """A MuJoCo env whose physics becomes ``config`` at step ``change_step`` of every episode.

    With ``config=None`` it is the unmodified env (the same code path for ID episodes). An
    episode whose simulation blows up ends with ``terminated=True`` and ``info["unstable"]``.
    Episode length is the caller's (wrap it in ``gym.wrappers.TimeLimit`` if needed).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, env_id: str, config: PerturbationConfig | None = None, change_step: int | None = None) -> None:
        if (config is None) != (change_step is None):
            raise ValueError(f"config={config!r}, change_step={change_step!r}: give both (a change) or neither (ID).")
        if config is not None:
            if not isinstance(config, PerturbationConfig):
                raise ValueError(f"config must be a PerturbationConfig (paper_lib.ood.mujoco), got {type(config).__name__}.")
            if config.env_id != env_id:
                raise ValueError(f"the perturbation is for {config.env_id} but env_id={env_id!r}: use one env.")
            if isinstance(change_step, bool) or not isinstance(change_step, (int, np.integer)) or change_step < 0:
                raise ValueError(f"change_step={change_step!r}: give the step (>= 0) at which the physics changes.")
        self.env_id, self.config = env_id, config
        self.change_step = None if change_step is None else int(change_step)
        self._id_env = make_single_env(env_id)
        self._perturbed_env = make_perturbed_env(config) if config is not None else None
        self.observation_space = self._id_env.observation_space
        self.action_space = self._id_env.action_space
        self._active = self._id_env.unwrapped
        self._t = 0

    @property
    def perturbed(self) -> bool:
        """Whether the physics has changed in this episode."""
        return self._perturbed_env is not None and self._active is self._perturbed_env.unwrapped

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self._active = self._id_env.unwrapped
        self._t = 0
        obs, info = self._active.reset(seed=seed, options=options)
        return obs, {**info, "perturbed": False, "unstable": False}

    def _switch(self) -> None:
        """Continue from the current state in the perturbed model."""
        source, target = self._id_env.unwrapped, self._perturbed_env.unwrapped
        target.reset()  # fresh MjData (warnings cleared); its random initial state is overwritten next
        target.data.time = source.data.time
        target.set_state(source.data.qpos.copy(), source.data.qvel.copy())
        self._active = target

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._perturbed_env is not None and self._t == self.change_step and not self.perturbed:
            self._switch()
        obs, reward, terminated, truncated, info = self._active.step(action)
        self._t += 1
        data = self._active.data
        unstable = is_unstable(obs) or any(data.warning[w].number > 0 for w in _INSTABILITY)
        return obs, float(reward), bool(terminated or unstable), bool(truncated), \
            {**info, "perturbed": self.perturbed, "unstable": unstable}

    def close(self) -> None:
        self._id_env.close()
        if self._perturbed_env is not None:
            self._perturbed_env.close()
