"""Putting a guard to work: an env wrapper that reports it, a policy wrapper that acts on it.

- ``GuardWrapper(env, guard)``: a gymnasium wrapper; every ``reset`` and ``step`` adds the guard's
  reading of the returned observation to ``info`` (``guard_score``, ``guard_statistic``,
  ``guard_flag``, ``guard_threshold``). It sees raw observations, so pass the agent's
  ``VecNormalize`` if it was trained with one: the guard scores what the policy sees.
- ``GuardedPolicy(model, guard, fallback=...)``: has SB3's ``predict`` signature, so it drops into
  ``evaluate_policy`` or any loop written for a ``PPO.load`` model; while an env is flagged its
  action comes from the fallback (zero action, another policy, a function) and/or ``on_alarm``
  is called (ask a human, log, stop). It scores the observations it is given, which under a
  ``VecNormalize`` env are already the normalized ones the policy sees.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.utils import is_vectorized_observation
from stable_baselines3.common.vec_env import VecNormalize

from paper_lib.guard.core import Guard, GuardMonitor, Reading, describe_model, model_fingerprint, needs_normalization


def _check_normalizer(guard: Guard, vecnormalize: VecNormalize | None) -> None:
    if vecnormalize is not None and not isinstance(vecnormalize, VecNormalize):
        raise ValueError(f"vecnormalize must be the agent's VecNormalize (VecNormalize.load(path, venv)), "
                         f"got {type(vecnormalize).__name__}.")
    if vecnormalize is None and needs_normalization(guard.model):
        raise ValueError("the agent acts on VecNormalize-d observations, so the guard must score those: pass "
                         "vecnormalize= the VecNormalize saved with the model (with training=False).")


def _check_guard_model(model: BaseAlgorithm, guard: Guard) -> None:
    """A guard calibrated on another model's scores sets its threshold for other weights: refuse it, naming both.
    An object that only has SB3's predict has no weights to compare; the guard scores with its own model."""
    if model is guard.model or not isinstance(model, (BaseAlgorithm, BasePolicy)) \
            or model_fingerprint(model) == model_fingerprint(guard.model):
        return
    raise ValueError(f"the guard was calibrated for {describe_model(guard.model)}, but the model given is "
                     f"{describe_model(model)}; its scores would not match the calibration. Pass the model the guard "
                     "was calibrated with, or calibrate a new guard for this model.")


class GuardWrapper(gym.Wrapper):
    """Adds the guard's score, statistic and flag of every returned observation to ``info``."""

    def __init__(self, env: gym.Env, guard: Guard, vecnormalize: VecNormalize | None = None) -> None:
        if not isinstance(guard, Guard):
            raise ValueError(f"guard must be a paper_lib Guard or SequentialGuard, got {type(guard).__name__}.")
        _check_normalizer(guard, vecnormalize)
        super().__init__(env)
        self.guard, self.vecnormalize = guard, vecnormalize
        if vecnormalize is not None:
            vecnormalize.training = False  # reading its statistics must not move them
        self.monitor = guard.monitor(1)
        self.last: Reading | None = None

    def _read(self, obs: np.ndarray, info: dict[str, Any]) -> dict[str, Any]:
        policy_obs = np.asarray(obs)[None]
        if self.vecnormalize is not None:
            policy_obs = self.vecnormalize.normalize_obs(policy_obs)
        self.last = reading = self.monitor.step(policy_obs)
        return {**info, "guard_score": float(reading.scores[0]), "guard_statistic": float(reading.statistics[0]),
                "guard_flag": bool(reading.flags[0]), "guard_threshold": self.guard.threshold}

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.monitor.reset()
        return obs, self._read(obs, info)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._read(obs, info)


@dataclass(frozen=True)
class Alarm:
    """What ``on_alarm`` receives for each flagged env at each flagged step."""

    env_index: int
    step: int  # steps since that env's episode started (0 = its first observation)
    score: float
    statistic: float
    threshold: float
    onset: bool  # the first flagged step of a run of flagged steps


class GuardedPolicy:
    """``model.predict`` with a guard in front: the fallback acts while an env is flagged.

    ``fallback``: ``"zero"`` (the zero action, continuous actions only), an object with SB3's
    ``predict`` (e.g. a conservative policy), a function ``obs_batch -> actions``, or None (keep the
    agent's action; useful with ``on_alarm`` alone). Episode starts reset the guard's statistic;
    ``evaluate_policy`` passes them, other loops should pass ``episode_start`` too.
    """

    def __init__(self, model: BaseAlgorithm, guard: Guard, fallback: Any = "zero",
                 on_alarm: Callable[[Alarm], None] | None = None) -> None:
        if not isinstance(guard, Guard):
            raise ValueError(f"guard must be a paper_lib Guard or SequentialGuard, got {type(guard).__name__}.")
        if not hasattr(model, "predict"):
            raise ValueError(f"model must have SB3's predict (e.g. PPO.load(path)), got {type(model).__name__}.")
        self.model, self.guard, self.on_alarm = model, guard, on_alarm
        self.action_space = model.action_space
        self.observation_space = model.observation_space
        if isinstance(fallback, str):
            if fallback != "zero":
                raise ValueError(f"fallback={fallback!r}: use 'zero', a policy with predict(), a function obs -> "
                                 "actions, or None.")
            if not isinstance(self.action_space, spaces.Box):
                raise ValueError("fallback='zero' needs continuous (Box) actions, where zero means 'no force'; for "
                                 f"{type(self.action_space).__name__} actions pass a policy or a function.")
        elif fallback is not None and not (callable(fallback) or hasattr(fallback, "predict")):
            raise ValueError(f"fallback must be 'zero', a policy with predict(), a function or None, got "
                             f"{type(fallback).__name__}.")
        if on_alarm is not None and not callable(on_alarm):
            raise ValueError(f"on_alarm must be a function of an Alarm, got {type(on_alarm).__name__}.")
        _check_guard_model(model, guard)
        self.fallback = fallback
        self.monitor: GuardMonitor | None = None
        self.last: Reading | None = None
        self.steps = self.flagged_steps = 0  # counted over envs and steps
        self._episode_step = np.zeros(0, dtype=np.int64)

    def reset(self) -> None:
        """Forget every episode (a new evaluation)."""
        self.monitor = None

    def _fallback_actions(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        if self.fallback == "zero":
            return np.zeros((len(obs), *self.action_space.shape), dtype=self.action_space.dtype)
        if hasattr(self.fallback, "predict"):
            return np.asarray(self.fallback.predict(obs, deterministic=deterministic)[0])
        return np.asarray(self.fallback(obs))

    def predict(self, observation: np.ndarray, state: tuple[np.ndarray, ...] | None = None,
                episode_start: np.ndarray | None = None, deterministic: bool = False
                ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        vectorized = is_vectorized_observation(observation, self.observation_space)
        obs = np.asarray(observation) if vectorized else np.asarray(observation)[None]
        n = len(obs)
        if self.monitor is None or self.monitor.n_envs != n:
            self.monitor = self.guard.monitor(n)
            self._episode_step = np.zeros(n, dtype=np.int64)
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            self.monitor.reset(starts)
            self._episode_step[starts] = 0
        self.last = reading = self.monitor.step(obs)
        actions, state = self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        actions = np.array(actions, copy=True)
        flagged = np.flatnonzero(reading.flags)
        if flagged.size:
            if self.on_alarm is not None:
                for i in flagged:
                    self.on_alarm(Alarm(int(i), int(self._episode_step[i]), float(reading.scores[i]),
                                        float(reading.statistics[i]), self.guard.threshold, bool(reading.onsets[i])))
            if self.fallback is not None:
                actions[flagged] = self._fallback_actions(obs[flagged], deterministic)
        self.steps += n
        self.flagged_steps += int(flagged.size)
        self._episode_step += 1
        return (actions if vectorized else actions[0]), state
