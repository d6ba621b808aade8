"""Is a stored study trial what its study trains today? Asked before trials are read or added.

Each trial records the settings it trained with (its `config` user attribute, written by the objective). The
search samples some of them; the rest come from the env's recipe in params.yaml (`hyperparameters`: n_envs,
normalization, policy settings, the members' defaults). When an env's recipe changes (issue 38's Walker2d),
the trials of its studies were made with the old one: notebook 9 shows such a study as "another recipe" and
leaves its trials out, and a worker refuses to add trials to it until it is deleted and trained again.
"""

from __future__ import annotations

import json
from typing import Any

import optuna

from paper_lib.agents.factory import resolve_run_config
from paper_lib.study.config import StudyConfig, StudySpec
from paper_lib.study.space import agent_kwargs

#: The settings a trial's `config` records (the objective writes these; older trials lack the normalization).
RECORDED_KEYS = ("algo", "method", "env_id", "seed", "n_envs", "n_members", "dropout_p", "masksembles_scale",
                 "hidden_sizes", "normalize_obs", "normalize_reward", "policy", "algo_kwargs", "inference",
                 "total_timesteps")


def expected_trial_config(cfg: StudyConfig, spec: StudySpec, params: dict[str, Any], seed: int) -> dict[str, Any]:
    """The `config` a trial with these sampled `params` and `seed` records when the study trains it today."""
    kwargs = agent_kwargs(params, spec.fixed, cfg.hyperparameters[spec.env_id])
    config = resolve_run_config(spec.algo, spec.method, spec.env_id, seed, inference=cfg.objective.inference,
                                **kwargs)
    config["total_timesteps"] = spec.total_timesteps or config["total_timesteps"]
    return {key: config.get(key) for key in RECORDED_KEYS}


def trial_differences(cfg: StudyConfig, spec: StudySpec, trial: optuna.trial.FrozenTrial) -> list[str]:
    """The recorded settings of a finished trial that differ from what its study trains today (empty: the same).
    A setting the trial did not record (older trials lack the normalization) is not compared."""
    stored = trial.user_attrs.get("config")
    if stored is None or "seed" not in trial.user_attrs:
        return []  # it never trained (a failed start): nothing of another recipe to read
    stored = json.loads(stored)
    try:
        expected = expected_trial_config(cfg, spec, trial.params, int(trial.user_attrs["seed"]))
    except ValueError as err:  # e.g. 8 sampled members where the recipe now has 4 envs
        return [f"params.yaml's recipe cannot train its settings any more ({err})"]
    expected = json.loads(json.dumps(expected, sort_keys=True, default=str))  # as the objective stores it
    return [f"{key}: trained with {stored[key]!r}, params.yaml gives {expected[key]!r}"
            for key in RECORDED_KEYS if key in stored and stored[key] != expected[key]]


def study_differences(cfg: StudyConfig, spec: StudySpec, study: optuna.Study) -> list[str]:
    """The differences of the study's first trial of another recipe (empty: every trial is of today's)."""
    for trial in study.get_trials(deepcopy=False):
        wrong = trial_differences(cfg, spec, trial)
        if wrong:
            return [f"trial {trial.number}: {w}" for w in wrong]
    return []


def other_recipe_studies(cfg: StudyConfig, storage: str | optuna.storages.BaseStorage) -> dict[str, str]:
    """Study name -> why, for every configured study in `storage` holding a trial of another recipe."""
    stored = set(optuna.get_all_study_names(storage=storage))
    found = {}
    for name, spec in cfg.studies.items():
        if name in stored:
            wrong = study_differences(cfg, spec, optuna.load_study(study_name=name, storage=storage))
            if wrong:
                found[name] = "; ".join(wrong)
    return found
