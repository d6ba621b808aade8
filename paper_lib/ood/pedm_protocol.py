"""PEDM's OOD protocol (Haider et al., AAMAS 2023) on gymnasium's MuJoCo v5 envs.

An episode starts in the default env; at a random step the dynamics change and stay changed. Every
transition is labelled 0 before that step and 1 from it on, so a detector is judged per step, and
also by how soon after the change it reacts. The authors' code (github.com/FraunhoferIKS/pedm-ood,
commit fbef8bb) sets it, ``mujoco_envs/anom_mj_env.py`` and ``mujoco_envs/mod_envs.py``:

- injection step ``np.random.randint(2, ep_length)``: uniform on 2..999 for 1000-step episodes
  (``mod_envs.py`` l. 84-85); the transition taken at step t (counting ``step`` calls from 0) is
  perturbed when t >= injection step (``anom_mj_env.py`` l. 49-76; ``oodd_runner.py`` l. 145 labels);
- at the injection step every body mass is multiplied by the factor and a constant force is set on one
  body (``anom_mj_env.py`` l. 39-43, ``xfrc_applied``: a force along world x); the inertias stay;
- from then on every action is offset, then scaled, then drawn from a normal around it
  (``anom_mj_env.py`` l. 59-64), before the env (and MuJoCo's control range) sees it;
- HalfCheetah's values, minor / severe (``mod_envs.py`` l. 62-81): mass x1.01 / x1.5, action x1.01 / x1.5,
  action offset 0.01 / 0.2, action noise std 0.01 / 0.2, force -0.1 / -15 N on ``ffoot``.

Translation to our four envs (docs/ood_benchmark.md has the table): all four have actions in [-1, 1]
like PEDM's cheetah, so the action and mass values carry over unchanged; the force keeps its share of
the robot's weight: ``value * total_mass / 14`` (PEDM's cheetah model sets ``settotalmass="14"``), on a
foot (HalfCheetah ``ffoot``, Walker2d ``foot``, Ant the front-left foot, Swimmer its last segment ``back``),
along -x, against the direction every one of them is rewarded to move.

Seeding: an episode reset with seed s draws its injection step and its action noise from
``default_rng(s)``, so the same episode seed gives the same injection step for every kind and severity
(the kinds are paired), and the same agent and seed replay the same episode.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import gymnasium as gym
import mujoco
import numpy as np

from paper_lib.agents.envs import MUJOCO_ENVS, check_env_seed, make_single_env
from paper_lib.ood.mujoco import is_unstable

KINDS = ("bm_factor", "act_factor", "act_offset", "act_noise", "force_vector")
SEVERITIES = ("minor", "severe")
HALF_CHEETAH_VALUES: dict[str, tuple[float, float]] = {
    "bm_factor": (1.01, 1.5), "act_factor": (1.01, 1.5), "act_offset": (0.01, 0.2),
    "act_noise": (0.01, 0.2), "force_vector": (-0.1, -15.0),
}
PEDM_CHEETAH_MASS = 14.0  # half_cheetah.xml, settotalmass
FOOT = {"HalfCheetah-v5": "ffoot", "Walker2d-v5": "foot", "Ant-v5": "aux_1/child", "Swimmer-v5": "back"}
FIRST_INJECTION = 2


def foot_body(model: mujoco.MjModel, env_id: str) -> int:
    """The id of the body the force acts on (Ant's feet are unnamed: the child of ``aux_1``)."""
    name = FOOT[env_id]
    if name.endswith("/child"):
        parent = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name.split("/")[0])
        return int(np.flatnonzero(model.body_parentid == parent)[0])
    return int(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name))


def perturbation_value(env_id: str, kind: str, severity: str, total_mass: float) -> float:
    """PEDM's HalfCheetah value for (kind, severity), the force rescaled to the robot's mass (HalfCheetah's as is)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}.")
    if severity not in SEVERITIES:
        raise ValueError(f"severity must be one of {SEVERITIES}, got {severity!r}.")
    value = HALF_CHEETAH_VALUES[kind][SEVERITIES.index(severity)]
    if kind != "force_vector" or env_id == "HalfCheetah-v5":  # our cheetah weighs PEDM's 14 kg (to 1e-7)
        return value
    return value * total_mass / PEDM_CHEETAH_MASS


class PEDMPerturbation(gym.Wrapper):
    """A MuJoCo v5 env perturbed from a random step of each episode on; ``info["ood_label"]`` per step.

    ``kind=None`` is the unperturbed env through the same code (ID episodes; labels all 0).
    ``injection_step`` fixes the step (tests); by default it is drawn per episode, uniform on
    2..episode_length - 1 as PEDM's. ``info`` also carries ``injection_step`` and ``unstable``.
    """

    def __init__(self, env: gym.Env, env_id: str, kind: str | None, severity: str = "severe",
                 injection_step: int | None = None, seed: int = 0) -> None:
        super().__init__(env)
        if env_id not in FOOT:
            raise ValueError(f"PEDM's protocol is defined for {tuple(FOOT)}, got {env_id!r}.")
        model = env.unwrapped.model
        self.env_id, self.kind, self.severity = env_id, kind, severity
        self.value = None if kind is None else perturbation_value(env_id, kind, severity, float(model.body_mass.sum()))
        if injection_step is not None and (isinstance(injection_step, bool) or int(injection_step) != injection_step
                                           or injection_step < 0):
            raise ValueError(f"injection_step must be an integer >= 0 or None (random), got {injection_step!r}.")
        self.fixed_step = injection_step
        self.episode_length = int(env.spec.max_episode_steps) if env.spec and env.spec.max_episode_steps else 1000
        self._rng = np.random.default_rng(check_env_seed(seed, "PEDMPerturbation"))
        self._nominal_mass = model.body_mass.copy()
        self._foot = foot_body(model, env_id)
        self._t = 0
        self.injection_step = -1

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(check_env_seed(seed, "PEDMPerturbation.reset"))
        self.unwrapped.model.body_mass[:] = self._nominal_mass
        obs, info = self.env.reset(seed=seed, options=options)
        self.unwrapped.data.xfrc_applied[:] = 0.0
        self._t = 0
        drawn = int(self._rng.integers(FIRST_INJECTION, self.episode_length))
        self.injection_step = -1 if self.kind is None else (drawn if self.fixed_step is None else int(self.fixed_step))
        return obs, {**info, "injection_step": self.injection_step}

    def _inject(self) -> None:
        if self.kind == "bm_factor":
            self.unwrapped.model.body_mass[:] = self._nominal_mass * self.value
        elif self.kind == "force_vector":
            self.unwrapped.data.xfrc_applied[self._foot, 0] = self.value

    def _perturb_action(self, action: np.ndarray) -> np.ndarray:
        action = np.asarray(action, dtype=float)
        if self.kind == "act_offset":
            return action + self.value
        if self.kind == "act_factor":
            return action * self.value
        if self.kind == "act_noise":
            return self._rng.normal(action, self.value)
        return action

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        label = int(self.kind is not None and self._t >= self.injection_step)
        if label and self._t == self.injection_step:
            self._inject()
        obs, reward, terminated, truncated, info = self.env.step(self._perturb_action(action) if label else action)
        self._t += 1
        unstable = is_unstable(obs)
        return obs, float(reward), bool(terminated or unstable), bool(truncated), \
            {**info, "ood_label": label, "injection_step": self.injection_step, "unstable": unstable}


def make_pedm_env(env_id: str, kind: str | None, severity: str = "severe", injection_step: int | None = None,
                  seed: int = 0) -> PEDMPerturbation:
    """Our default env of ``env_id`` (``make_single_env``) under PEDM's perturbation."""
    if env_id not in MUJOCO_ENVS:
        raise ValueError(f"PEDM's protocol runs on the MuJoCo envs {MUJOCO_ENVS}, got {env_id!r}.")
    return PEDMPerturbation(make_single_env(env_id), env_id, kind, severity, injection_step, seed)


class Agent(Protocol):
    def predict(self, observation: np.ndarray, deterministic: bool = ...) -> tuple[np.ndarray, Any]: ...


def episode_seeds(seed: int, n_episodes: int) -> list[int]:
    """Env seeds of the episodes of one collection: the same for every kind, so kinds are paired."""
    return [int(s) for s in np.random.SeedSequence(check_env_seed(seed, "episode_seeds")).generate_state(n_episodes)]


def play_pedm_episodes(agent: Agent, env_id: str, kind: str | None, severity: str = "severe", n_episodes: int = 100,
                       seed: int = 0, deterministic: bool = True,
                       policy_obs: Callable[[np.ndarray], np.ndarray] | None = None,
                       max_steps: int | None = None, injection_step: int | None = None) -> dict[str, np.ndarray]:
    """Play ``n_episodes`` and record every transition: obs, action, next_obs, reward, label, episode, step.

    ``action`` is what the agent chose (PEDM records the policy's action; the env perturbs it after);
    ``obs``/``next_obs`` are the env's raw observations, and ``policy_obs`` maps them to what the agent
    reads (a checkpoint's VecNormalize ``normalize_obs``). ``injection_step`` is per transition (-1 for
    ID episodes); an episode that ends before it has only label 0 (PEDM drops such episodes from its
    metrics, ``oodd_runner.py`` l. 142-144; `scoring.metrics.injection_metrics` does too). ``unstable``
    marks the step where a simulation blew up (that episode ends there). ``max_steps`` and a fixed
    ``injection_step`` are for short tests; the protocol plays whole episodes with a random step.
    """
    if isinstance(n_episodes, bool) or not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be a positive integer, got {n_episodes!r}.")
    env = make_pedm_env(env_id, kind, severity, injection_step=injection_step, seed=seed)
    rows: dict[str, list] = {k: [] for k in ("obs", "action", "next_obs", "reward", "label", "episode", "step",
                                             "injection_step", "unstable")}
    try:
        for ep, ep_seed in enumerate(episode_seeds(seed, n_episodes)):
            obs, _ = env.reset(seed=ep_seed)
            t, done = 0, False
            while not done and (max_steps is None or t < max_steps):
                action, _ = agent.predict(obs if policy_obs is None else policy_obs(obs), deterministic=deterministic)
                action = np.asarray(action, dtype=float).reshape(env.action_space.shape)
                next_obs, reward, terminated, truncated, info = env.step(action)
                for key, value in (("obs", obs), ("action", action), ("next_obs", next_obs), ("reward", reward),
                                   ("label", info["ood_label"]), ("episode", ep), ("step", t),
                                   ("injection_step", info["injection_step"]), ("unstable", info["unstable"])):
                    rows[key].append(value)
                obs, t, done = next_obs, t + 1, terminated or truncated
    finally:
        env.close()
    return {k: np.asarray(v) for k, v in rows.items()}
