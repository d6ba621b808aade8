"""The guard experiment (notebook 8): calibrated guards on a trained agent, physics changing mid-episode.

For one checkpoint, with one numpy seed (the same env gets the same episode plans for every
method, so methods face the same changes):

1. ID episodes of ``episode_steps`` steps in the default env, in four disjoint groups: ``fit``
   (half fit the member-free detectors, half are the ``reference`` for the CUSUM drift and the
   rank combination), ``calibration`` and ``id_test``.
2. Guards per score: ``state`` (one state per calibration episode at a uniformly random step, so
   the calibration states are i.i.d. draws of "a state at a random step of an ID episode"),
   ``window`` and ``cusum`` (per-episode maxima of the calibration episodes).
3. ``perturbed`` episodes: a stable random physics configuration (paper_lib.ood.mujoco) takes
   over at a uniform step in ``change_steps``; each guard's first alarm after the change gives
   the detection delay, an alarm at or before it is a false alarm.
4. The same perturbed episodes again with a ``GuardedPolicy`` (window guard, zero-action
   fallback) for each of ``fallback_scores``: the return with and without the fallback.

Scores of the unguarded episodes are computed after the rollouts, in batches; they equal the
step-by-step scores (per-state MC masks), so the guards see what they would see online.
"""

from __future__ import annotations

import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch as th
from stable_baselines3.common.vec_env import VecNormalize

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.guard.core import Guard, SequentialGuard
from paper_lib.guard.scores import CombinedScore, Score, available_scores, make_score, score_many
from paper_lib.guard.sequential import Cusum, WindowMean
from paper_lib.guard.settings import GuardSettings
from paper_lib.guard.shift import MidEpisodeShift
from paper_lib.guard.wrappers import GuardedPolicy
from paper_lib.ood.collect import ActionMode
from paper_lib.ood.mujoco import SUPPORTED_ENVS, PerturbationConfig, UnstablePerturbationWarning, sample_stable_config

GUARD_KINDS = ("state", "window", "cusum")
ID_KINDS = ("fit", "reference", "calibration", "id_test")
#: Perturbed episodes whose simulation blows up under the agent are redrawn at most this often in a row.
MAX_REDRAWS = 20


@dataclass
class Plan:
    """One episode to run: its seeds and, for a perturbed episode, the change."""

    kind: str
    index: int
    env_seed: int
    torch_seed: int
    config: PerturbationConfig | None = None
    change_step: int | None = None


@dataclass
class Episode:
    plan: Plan
    obs: np.ndarray  # (T, *obs_shape): s_0 .. s_{T-1} as the policy saw them
    rewards: np.ndarray  # (T,): reward of the action taken at s_t
    unstable: bool = False
    fallback: np.ndarray | None = None  # (T,) bool: the fallback chose the action at s_t (guarded runs)

    def post_change_return(self) -> float:
        return float(self.rewards[self.plan.change_step:].sum())


@dataclass
class GuardRun:
    """Everything notebook 8 tabulates for one checkpoint."""

    episodes: pd.DataFrame  # one row per (score, guard, test episode)
    returns: pd.DataFrame  # one row per (fallback score, perturbed episode)
    traces: pd.DataFrame  # the first perturbed episode, per step, for the fallback scores' window guards
    guards: dict[tuple[str, str], Guard] = field(repr=False)
    n_redrawn: int = 0  # perturbed configurations redrawn because the agent's episode blew up


# ------------------------------------------------------------------------------ rollouts


def _seeds(rng: np.random.Generator) -> tuple[int, int]:
    return int(rng.integers(2**31 - 1)), int(rng.integers(2**31 - 1))


def plan_id_episodes(settings: GuardSettings, rng: np.random.Generator) -> list[Plan]:
    half = settings.fit_episodes // 2
    counts = {"fit": half, "reference": settings.fit_episodes - half,
              "calibration": settings.calibration_episodes, "id_test": settings.id_test_episodes}
    return [Plan(kind, i, *_seeds(rng)) for kind in ID_KINDS for i in range(counts[kind])]


def draw_change(env_id: str, settings: GuardSettings, rng: np.random.Generator, kind: str, index: int) -> Plan:
    """A perturbed episode: a configuration that survives random actions, and a uniform change step."""
    with warnings.catch_warnings():  # redraws are counted by the caller, not reported one by one
        warnings.simplefilter("ignore", UnstablePerturbationWarning)
        config = sample_stable_config(env_id, rng)
    change = int(rng.integers(settings.change_steps[0], settings.change_steps[1] + 1))
    return Plan(kind, index, *_seeds(rng), config=config, change_step=change)


def run_episode(model: Any, env_id: str, plan: Plan, steps: int, deterministic: bool,
                vecnormalize: VecNormalize | None = None, actor: GuardedPolicy | None = None) -> Episode:
    """One episode of at most ``steps`` steps; ``actor`` (a GuardedPolicy) acts instead of the model if given."""
    env = MidEpisodeShift(env_id, plan.config, plan.change_step)
    actor_ = model if actor is None else actor
    obs_list, rewards, fallback = [], [], []
    unstable = False
    try:
        obs, _ = env.reset(seed=plan.env_seed)
        with th.random.fork_rng(devices=[]):
            th.manual_seed(plan.torch_seed)
            for t in range(steps):
                policy_obs = obs[None] if vecnormalize is None else vecnormalize.normalize_obs(obs[None])
                obs_list.append(policy_obs[0])
                action, _ = actor_.predict(policy_obs, episode_start=np.array([t == 0]), deterministic=deterministic)
                if actor is not None:
                    fallback.append(bool(actor.last.flags[0]) and actor.fallback is not None)
                obs, reward, terminated, truncated, info = env.step(action[0])
                rewards.append(reward)
                if terminated or truncated:
                    unstable = bool(info.get("unstable"))
                    break
    finally:
        env.close()
    return Episode(plan, np.stack(obs_list), np.asarray(rewards, dtype=float), unstable,
                   np.asarray(fallback, dtype=bool) if actor is not None else None)


def run_perturbed(model: Any, env_id: str, settings: GuardSettings, rng: np.random.Generator, deterministic: bool,
                  vecnormalize: VecNormalize | None) -> tuple[list[Episode], int]:
    """The perturbed test episodes; a configuration that blows up under the agent is redrawn."""
    episodes, redrawn = [], 0
    for i in range(settings.perturbed_episodes):
        for _ in range(MAX_REDRAWS):
            episode = run_episode(model, env_id, draw_change(env_id, settings, rng, "perturbed", i),
                                  settings.episode_steps, deterministic, vecnormalize)
            if not episode.unstable:
                break
            redrawn += 1
        else:
            raise RuntimeError(f"{MAX_REDRAWS} perturbed {env_id} episodes in a row blew up under the agent; "
                               "narrow the perturbation ranges.")
        episodes.append(episode)
    return episodes, redrawn


# ------------------------------------------------------------------------------- scoring


def build_scores(model: Any, fit_obs: np.ndarray, reference_obs: np.ndarray, settings: GuardSettings
                 ) -> dict[str, Score]:
    """Every score that applies to the model: member measures, the four detectors, the combination."""
    scores: dict[str, Score] = {name: make_score(model, name, fit_states=fit_obs) for name in available_scores(model)}
    if settings.combine and all(name in scores for name in settings.combine):
        combined = CombinedScore([scores[name] for name in settings.combine], reference_obs)
        scores[combined.name] = combined
    return scores


def score_episodes(scores: dict[str, Score], episodes: list[Episode]) -> dict[str, list[np.ndarray]]:
    """Per score, one per-step score array per episode (all episodes scored in one batch)."""
    if not episodes:
        return {name: [] for name in scores}
    lengths = np.cumsum([len(e.obs) for e in episodes])[:-1]
    flat = score_many(scores, np.concatenate([e.obs for e in episodes]))
    return {name: np.split(values, lengths) for name, values in flat.items()}


def build_guards(model: Any, scores: dict[str, Score], calibration: dict[str, list[np.ndarray]],
                 reference: dict[str, np.ndarray], settings: GuardSettings, rng: np.random.Generator
                 ) -> dict[tuple[str, str], Guard]:
    """State, window and CUSUM guards per score, all calibrated on the same held-out episodes."""
    n = len(next(iter(calibration.values())))
    steps = [int(rng.integers(len(e))) for e in next(iter(calibration.values()))]  # one random state per episode
    guards: dict[tuple[str, str], Guard] = {}
    for name, score in scores.items():
        per_episode = calibration[name]
        assert len(per_episode) == n
        alpha, confidence = settings.alpha, settings.confidence
        guards[name, "state"] = Guard.from_scores(model, score, [e[t] for e, t in zip(per_episode, steps)], alpha,
                                                  confidence)
        guards[name, "window"] = SequentialGuard.from_episode_scores(model, score, per_episode, alpha,
                                                                     WindowMean(settings.window), confidence)
        guards[name, "cusum"] = SequentialGuard.from_episode_scores(
            model, score, per_episode, alpha, Cusum.from_reference(reference[name], settings.cusum_quantile),
            confidence)
    return guards


def evaluate_guards(guards: dict[tuple[str, str], Guard], streams: dict[str, list[np.ndarray]],
                    episodes: list[Episode]) -> pd.DataFrame:
    """One row per (score, guard, episode): flagged steps, any alarm, and for a change its delay."""
    rows = []
    for (name, kind), guard in guards.items():
        for episode, scores in zip(episodes, streams[name]):
            flags = guard.alarms(scores)
            plan = episode.plan
            row = {"score": name, "guard": kind, "alpha": guard.alpha, "confidence": guard.confidence,
                   "n_calibration": guard.n_calibration,
                   "threshold": guard.threshold, "episode_kind": "perturbed" if plan.config else "id",
                   "episode": plan.index, "steps": len(flags), "flagged_steps": int(flags.sum()),
                   "any_alarm": bool(flags.any()), "change_step": plan.change_step, "delay": np.nan,
                   "alarm_before_change": False, "reached_change": plan.config is not None,
                   "perturbation": "+".join(plan.config.kinds) if plan.config else "id"}
            if plan.config is not None:
                c = plan.change_step
                row["reached_change"] = len(flags) > c + 1  # an episode that ended before the change never saw it
                row["alarm_before_change"] = bool(flags[:c + 1].any())  # s_0..s_c come from the default physics
                after = np.flatnonzero(flags[c + 1:])
                if after.size:
                    row["delay"] = float(after[0] + 1)  # s_{c+d} is the d-th state of the new physics
            rows.append(row)
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------- the whole run


def _share(flags: np.ndarray) -> float:
    return float(flags.mean()) if flags.size else float("nan")


def run_experiment(checkpoint: Checkpoint, settings: GuardSettings, action_mode: ActionMode, seed: int,
                   guards_dir: str | Path | None = None) -> GuardRun:
    """Guards for every score of one checkpoint, their false alarms, delays and fallback returns."""
    env_id = checkpoint.config["env_id"]
    if env_id not in SUPPORTED_ENVS:
        raise ValueError(f"the guard experiment perturbs MuJoCo physics; {env_id} is not one of {list(SUPPORTED_ENVS)}.")
    model = checkpoint.model
    action_mode.apply(model.policy)
    vecnormalize = checkpoint.env(1, seed) if checkpoint.vecnormalize_path is not None else None
    rng = np.random.default_rng([seed, zlib.crc32(env_id.encode())])  # same plans for every method of an env
    det, steps = action_mode.deterministic, settings.episode_steps

    id_episodes = [run_episode(model, env_id, plan, steps, det, vecnormalize) for plan in plan_id_episodes(settings, rng)]
    by_kind = {kind: [e for e in id_episodes if e.plan.kind == kind] for kind in ID_KINDS}
    perturbed, redrawn = run_perturbed(model, env_id, settings, rng, det, vecnormalize)

    fit_obs = np.concatenate([e.obs for e in by_kind["fit"]])
    reference_obs = np.concatenate([e.obs for e in by_kind["reference"]])
    scores = build_scores(model, fit_obs, reference_obs, settings)
    reference = score_many(scores, reference_obs)
    calibration = score_episodes(scores, by_kind["calibration"])
    guards = build_guards(model, scores, calibration, reference, settings, rng)

    tests = by_kind["id_test"] + perturbed
    test_streams = score_episodes(scores, tests)
    frame = evaluate_guards(guards, test_streams, tests)

    returns, traces = [], []
    for name in settings.fallback_scores:
        if name not in scores:
            continue
        guard = guards[name, "window"]
        guarded = GuardedPolicy(model, guard, fallback=settings.fallback)
        for episode in perturbed:
            with_fallback = run_episode(model, env_id, episode.plan, steps, det, vecnormalize, actor=guarded)
            c = episode.plan.change_step
            returns.append({"score": name, "guard": "window", "episode": episode.plan.index, "change_step": c,
                            "reached_change": len(episode.rewards) > c and len(with_fallback.rewards) > c,
                            "perturbation": "+".join(episode.plan.config.kinds),
                            "return_without": float(episode.rewards.sum()),
                            "return_with": float(with_fallback.rewards.sum()),
                            "post_change_return_without": episode.post_change_return(),
                            "post_change_return_with": with_fallback.post_change_return(),
                            "fallback_share_after_change": _share(with_fallback.fallback[c:]),
                            "fallback_steps_before_change": int(with_fallback.fallback[:c].sum()),
                            "unstable_with": with_fallback.unstable})
        first = perturbed[0]
        trace_scores = test_streams[name][len(by_kind["id_test"])]
        traces.append(pd.DataFrame({"score": name, "step": np.arange(len(trace_scores)), "value": trace_scores,
                                    "statistic": guard.statistic_path(trace_scores), "threshold": guard.threshold,
                                    "change_step": first.plan.change_step,
                                    "perturbation": first.plan.config.describe()}))
        if guards_dir is not None:
            guard.save(guards_dir)
    return GuardRun(frame, pd.DataFrame(returns), pd.concat(traces, ignore_index=True) if traces else pd.DataFrame(),
                    guards, redrawn)
