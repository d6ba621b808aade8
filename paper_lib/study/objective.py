"""One trial: train a configuration, then score it on the two objectives (paper section 5).

1. reward: the mean evaluation return over `eval_episodes` episodes (combined inference for
   member methods; deterministic or sampled actions as `study.objective` says);
2. OOD AUROC: the trained agent collects ID states; half of them are kept apart to fit the
   member-free detectors, the other half plus a noisy copy of it (uniform noise of 2x the
   element-wise ID std, `paper_lib.ood.collect.noise_ood_states`) are scored, OOD positive.
   Member methods are scored by `objective.measure`, baselines by a member-free detector.

Everything else each measure and detector gives is kept with the trial too. The states are
scored in one batch, so methods that draw masks per batch (MC DropConnect) score the ID and
the OOD states with the same masks.
"""

from __future__ import annotations

import json
import math
import os
import socket
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from stable_baselines3.common.evaluation import evaluate_policy

from paper_lib.agents.checkpoints import Checkpoint, load_checkpoint
from paper_lib.agents.training import train_run
from paper_lib.measures.detectors import KNNDetector, MahalanobisDetector, split_fit_eval
from paper_lib.measures.estimates import policy_features
from paper_lib.ood.collect import ActionMode, collect_id_states, noise_ood_states
from paper_lib.scoring.ood_scores import score_dataset
from paper_lib.ood.datasets import concat
from paper_lib.scoring.metrics import detection_metrics
from paper_lib.study.config import StudyConfig, StudySpec
from paper_lib.study.recipe import RECORDED_KEYS
from paper_lib.study.space import agent_kwargs, suggest_params

#: Never write resume points for a trial: a killed trial is retried from its start.
NO_RESUME_POINTS = 10**15


class TrialFailed(RuntimeError):
    """A trial that ran but produced nothing to rank (NaN or infinite reward or scores)."""


@dataclass
class TrialResult:
    reward: float
    auroc: float
    attrs: dict[str, Any]


def evaluation_episodes(checkpoint: Checkpoint, episodes: int, seed: int, deterministic: bool) -> list[float]:
    """`episodes` evaluation returns (member policies act with their saved, combined inference mode)."""
    env = checkpoint.env(1, seed)
    try:
        rewards, _ = evaluate_policy(checkpoint.model, env, n_eval_episodes=episodes, deterministic=deterministic,
                                     return_episode_rewards=True)
    finally:
        env.close()
    return [float(r) for r in rewards]


def noise_aurocs(checkpoint: Checkpoint, cfg: StudyConfig, seed: int) -> dict[str, float]:
    """AUROC (OOD positive) of every member measure and member-free detector on the noise OOD set."""
    o = cfg.objective
    model, env_id = checkpoint.model, checkpoint.config["env_id"]
    vecnormalize = checkpoint.env(1, seed) if checkpoint.vecnormalize_path is not None else None
    mode = ActionMode(deterministic=o.collect_deterministic, inference=o.inference)
    id_states = collect_id_states(model, env_id, cfg.n_id_states, action_mode=mode, seed=seed,
                                  max_episode_steps=cfg.max_episode_steps, skip_first=cfg.skip_first,
                                  vecnormalize=vecnormalize)
    rng = np.random.default_rng(seed)
    fit_idx, _ = split_fit_eval(len(id_states), rng)
    mask = np.zeros(len(id_states), dtype=bool)
    mask[fit_idx] = True
    id_fit, id_eval = id_states.subset(mask), id_states.subset(~mask)
    noise = noise_ood_states(id_eval, rng, magnitude=o.noise_magnitude, vecnormalize=vecnormalize)
    both = concat(id_eval, noise)
    scores = score_dataset(model, both, batch_size=len(both))
    labels = scores["label"].to_numpy()

    def obs(data):
        return data.states if data.policy_obs is None else data.policy_obs

    inputs_fit = {"obs": obs(id_fit), "features": policy_features(model.policy, obs(id_fit))}
    inputs = {"obs": obs(both), "features": policy_features(model.policy, obs(both))}
    for name, detector in (("mahalanobis", MahalanobisDetector), ("knn", KNNDetector)):
        for space in ("obs", "features"):
            scores[f"{name}_{space}"] = detector().fit(inputs_fit[space]).score(inputs[space])
    measures = [c for c in scores.columns if c not in ("label", "source", "episode", "step", "config_index")]
    return {m: detection_metrics(scores.loc[labels == 0, m], scores.loc[labels == 1, m])["auroc"] for m in measures}


def run_configuration(cfg: StudyConfig, spec: StudySpec, params: dict[str, Any], seed: int,
                      workdir: Path) -> TrialResult:
    """Train `params` (plus the budget's fixed settings) with `seed` and score it; raises TrialFailed on NaN."""
    kwargs = agent_kwargs(params, spec.fixed, cfg.hyperparameters[spec.env_id])
    kwargs["inference"] = cfg.objective.inference
    start = time.perf_counter()
    folder = train_run(spec.env_id, spec.method, seed, workdir / "run", algo=spec.algo,
                       total_timesteps=spec.total_timesteps, agent_kwargs=kwargs, resume=False,
                       resume_every=NO_RESUME_POINTS)
    train_seconds = time.perf_counter() - start
    checkpoint = load_checkpoint(folder, spec.env_id, spec.method, seed)
    curve = checkpoint.training_curve()
    rewards = evaluation_episodes(checkpoint, cfg.eval_episodes, seed + 1, cfg.objective.deterministic_reward)
    reward, reward_std = float(np.mean(rewards)), float(np.std(rewards))
    if not math.isfinite(reward):
        raise TrialFailed(f"evaluation reward is {reward} (the policy or the env diverged)")
    aurocs = noise_aurocs(checkpoint, cfg, seed + 2)
    measure = cfg.objective.auroc_measure(spec.method)
    auroc = aurocs.get(measure, float("nan"))
    if not math.isfinite(auroc):
        raise TrialFailed(f"AUROC of {measure} is {auroc} (scores were NaN or constant: {aurocs})")
    config = checkpoint.config
    attrs = {"reward_std": reward_std, "train_seconds": train_seconds, "seconds": time.perf_counter() - start,
             "trained_timesteps": config["trained_timesteps"],
             "final_training_reward": float(curve["reward"].iloc[-1]) if len(curve) else float("nan"),
             "auroc_measure": measure, **{f"auroc_{k}": v for k, v in aurocs.items()},
             "config": json.dumps({k: config.get(k) for k in RECORDED_KEYS}, sort_keys=True, default=str)}
    return TrialResult(reward, auroc, attrs)


def worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


class Objective:
    """The Optuna objective of one study: settings and seed recorded first, then train and score.

    A retried trial (queued again after its worker died) gets the same settings from Optuna and
    the same seed from its copied user attributes, so it repeats the lost run exactly. Any
    error is recorded as the trial's `fail_reason` before Optuna marks it FAIL.
    """

    def __init__(self, cfg: StudyConfig, spec: StudySpec) -> None:
        self.cfg, self.spec = cfg, spec

    def __call__(self, trial: optuna.Trial) -> tuple[float, float]:
        seed = int(trial.user_attrs.get("seed", self.cfg.seed + trial.number))
        trial.set_user_attr("seed", seed)
        trial.set_user_attr("worker", worker_id())
        try:
            params = suggest_params(trial, self.spec.space)
            trial.set_user_attr("fixed", json.dumps(self.spec.fixed, sort_keys=True))
            with tempfile.TemporaryDirectory(prefix=f"study-{self.spec.name}-{trial.number}-") as tmp:
                result = run_configuration(self.cfg, self.spec, params, seed, Path(tmp))
        except Exception as err:
            trial.set_user_attr("fail_reason", f"{type(err).__name__}: {err}"[:2000])
            raise
        for key, value in result.attrs.items():
            trial.set_user_attr(key, value)
        return result.reward, result.auroc
