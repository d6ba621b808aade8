"""The OOD guard: its conformal guarantees (statistically, over many calibration splits), detection of
an abrupt change, the env and policy wrappers with PPO.load and evaluate_policy, persistence, bad
inputs, and notebook 8 on a tiny budget."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
import torch as th
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from paper_lib import make_agent
from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.agents.envs import make_single_env
from paper_lib.guard import (
    CallableScore,
    CombinedScore,
    Cusum,
    Guard,
    GuardedPolicy,
    GuardWrapper,
    MidEpisodeShift,
    SequentialGuard,
    WindowMean,
    conformal_threshold,
    make_score,
)
from paper_lib.guard.conformal import conformal_rank, false_alarm_bound, min_calibration_size
from paper_lib.guard.experiment import Plan, run_episode
from paper_lib.guard.settings import load_settings, parse_settings
from paper_lib.ood.collect import ActionMode
from paper_lib.ood.mujoco import PerturbationConfig

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
ENV = "HalfCheetah-v5"
#: The notebook test's guard budget when params.yaml has no `guard` section yet.
TEST_GUARD = {"alpha": 0.2, "window": 3, "cusum_quantile": 0.9, "fallback": "zero",
              "fallback_scores": ["value_std", "mahalanobis_obs"], "combine": ["value_std", "mahalanobis_obs"],
              "budgets": {"tiny": {"fit_episodes": 4, "calibration_episodes": 6, "id_test_episodes": 2,
                                   "perturbed_episodes": 2, "episode_steps": 30, "change_steps": [8, 20]}}}


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def tiny_repo(tmp_path_factory) -> Path:
    """params.yaml with the tiny profile active, and its two checkpoints trained (256 steps each)."""
    from paper_lib.pipeline.stages import train_stage

    root = tmp_path_factory.mktemp("guard_repo")
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["run"] = {"profile": "tiny", **params["profiles"]["tiny"]}
    params.setdefault("guard", TEST_GUARD)
    params["hyperparameters"][ENV]["normalize_obs"] = False  # the raw-observation path; normalized: the Walker2d test
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    cfg, _ = load_settings(root / "params.yaml")
    for env_id, method, seed in cfg.runs():
        train_stage(cfg, env_id, method, seed, resume=False)
    return root


@pytest.fixture(scope="module")
def tiny_models(tiny_repo):
    """The tiny checkpoints, loaded with plain PPO.load (through load_checkpoint)."""
    cfg, _ = load_settings(tiny_repo / "params.yaml")
    return {method: load_checkpoint(cfg.checkpoint_dir(ENV, method, 0), ENV, method, 0)
            for method in ("baseline", "masksembles")}


@pytest.fixture(scope="module")
def id_episodes(tiny_models):
    """24 ID episodes of 40 steps of the tiny Masksembles agent (sampled actions), as policy observations."""
    model = tiny_models["masksembles"].model
    rng = np.random.default_rng(0)
    return [run_episode(model, ENV, Plan("id", i, int(rng.integers(2**31 - 1)), i), 40, False).obs for i in range(24)]


def _cartpole_model():
    return PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu")


# ---------------------------------------------------------------- the conformal threshold


def test_threshold_is_the_conformal_order_statistic():
    scores = np.arange(1.0, 20.0)  # n = 19
    assert conformal_threshold(scores, 0.05) == 19.0  # k = ceil(20 * 0.95) = 19: the largest
    assert conformal_threshold(scores, 0.1) == 18.0  # k = ceil(20 * 0.9) = 18
    assert conformal_threshold(scores, 0.5) == 10.0  # k = ceil(20 * 0.5) = 10
    assert min_calibration_size(0.05) == 19 and min_calibration_size(0.1) == 9 and min_calibration_size(0.3) == 3
    assert false_alarm_bound(19, 0.05) == pytest.approx(0.05)


def test_false_alarm_rate_stays_within_the_bound_over_200_splits_of_exchangeable_scores():
    """i.i.d. scores: over 200 calibration/test splits the mean false-alarm rate is alpha's exact bound."""
    rng = np.random.default_rng(0)
    model, alpha, n, m = _cartpole_model(), 0.1, 14, 200  # naive ceil(n(1-alpha)) would give k = 13, not 14
    score = CallableScore(lambda s: s[:, 0], "first_coordinate")
    rates = []
    for _ in range(200):
        pool = rng.exponential(size=n + m)
        guard = Guard.from_scores(model, score, pool[:n], alpha)
        rates.append(np.mean(pool[n:] > guard.threshold))
    mean, se = np.mean(rates), np.std(rates) / math.sqrt(len(rates))
    assert mean <= alpha + 3 * se
    assert mean >= false_alarm_bound(n, alpha) - 4 * se  # tight, not vacuous: (n + 1 - k) / (n + 1) = 0.1


def test_confidence_bounds_each_guards_own_rate_not_only_the_average():
    """Exponential(1) scores, so a threshold q's true false-alarm rate is exp(-q). Over 400 calibration sets,
    the marginal guard's own rate exceeds alpha in about half of them; with confidence 0.9 in at most ~10%."""
    rng = np.random.default_rng(4)
    model, score, alpha, n = _cartpole_model(), CallableScore(lambda s: s[:, 0], "x"), 0.1, 60
    marginal, confident = [], []
    for _ in range(400):
        calibration = rng.exponential(size=n)
        marginal.append(np.exp(-Guard.from_scores(model, score, calibration, alpha).threshold))
        guard = Guard.from_scores(model, score, calibration, alpha, confidence=0.9)
        confident.append(np.exp(-guard.threshold))
    assert np.mean(np.array(marginal) > alpha) > 0.3  # the average bound says nothing about one guard
    assert np.mean(np.array(confident) > alpha) <= 0.1 + 3 * math.sqrt(0.09 / 400)
    assert np.mean(confident) == pytest.approx(guard.expected_false_alarm_rate, abs=0.01)  # (n + 1 - k) / (n + 1)
    assert "with probability >= 0.9" in guard.guarantee() and "confidence=0.9" in repr(guard)
    # the rank: smallest k with P(Beta(n+1-k, k) > alpha) <= 0.1; at n = 45 only the largest score (0.95^45 < 0.1)
    assert conformal_rank(45, 0.05, 0.9) == 45 and min_calibration_size(0.05, 0.9) == 45
    assert conformal_rank(100, 0.05, 0.9) == 99 and conformal_rank(100, 0.05) == 96
    with pytest.raises(ValueError, match=r"alpha=0.05 at confidence=0.9 needs at least 45 calibration states"):
        Guard.from_scores(model, score, np.arange(44.0), 0.05, confidence=0.9)
    with pytest.raises(ValueError, match=r"confidence=1.5: give the probability"):
        Guard.from_scores(model, score, np.arange(44.0), 0.05, confidence=1.5)


@pytest.mark.parametrize("score_name", ["value_std", "mahalanobis_obs"])
def test_false_alarm_rate_on_real_scores_of_a_trained_agent_over_200_splits(tiny_models, id_episodes, score_name):
    """Real ID states of the tiny agent, split at random 200 times into calibration and test states:
    a random split makes them exchangeable, so the conformal bound holds for the empirical rate."""
    model = tiny_models["masksembles"].model
    score = make_score(model, score_name, fit_states=np.concatenate(id_episodes[:6]))
    states = np.concatenate(id_episodes[6:])  # held out from the detector's fit
    values = score(states)
    rng, alpha, n = np.random.default_rng(1), 0.1, 24  # k = 23 (the naive quantile: 22)
    rates = []
    for _ in range(200):
        perm = rng.permutation(len(values))
        guard = Guard.from_scores(model, score, values[perm[:n]], alpha)
        rates.append(np.mean(values[perm[n:]] > guard.threshold))
    mean, se = np.mean(rates), np.std(rates) / math.sqrt(len(rates))
    assert mean <= alpha + 3 * se
    assert mean > 0.5 * alpha  # the guard is not trivially silent
    direct = Guard(model, score, states[:n], alpha)  # the same threshold when the guard scores the states itself
    # up to float rounding: Masksembles scores many states on each member's kept units only (a different
    # summation order than the few states here; paper_lib.methods.inference.COMPACT_MIN_STATES)
    assert direct.threshold == pytest.approx(Guard.from_scores(model, score, values[:n], alpha).threshold, rel=1e-6)


def _ar1_episodes(rng: np.random.Generator, count: int, length: int) -> list[np.ndarray]:
    """Score streams correlated within an episode (AR(1), x_t = 0.8 x_{t-1} + 0.6 e_t) and independent across episodes."""
    from scipy.signal import lfilter

    noise = rng.normal(size=(count, length))
    noise[:, 1:] *= 0.6  # x_0 ~ N(0, 1), the stationary law
    return list(lfilter([1.0], [1.0, -0.8], noise, axis=1))


@pytest.mark.parametrize("statistic", [WindowMean(5), Cusum(0.5)], ids=["window", "cusum"])
def test_per_episode_alarm_rate_stays_within_the_bound_over_200_splits(statistic):
    model, alpha, n, m = _cartpole_model(), 0.1, 14, 60
    score = CallableScore(lambda s: s[:, 0], "synthetic")
    rng = np.random.default_rng(2)
    rates, per_state_rates = [], []
    for _ in range(200):
        episodes = _ar1_episodes(rng, n + m, 50)
        guard = SequentialGuard.from_episode_scores(model, score, episodes[:n], alpha, statistic)
        rates.append(np.mean([guard.alarms(e).any() for e in episodes[n:]]))
        one_state_each = [e[rng.integers(len(e))] for e in episodes[:n]]
        state_guard = Guard.from_scores(model, score, one_state_each, alpha)
        per_state_rates.append(np.mean([state_guard.alarms(e).any() for e in episodes[n:]]))
    mean, se = np.mean(rates), np.std(rates) / math.sqrt(len(rates))
    assert mean <= alpha + 3 * se
    assert mean >= false_alarm_bound(n, alpha) - 4 * se
    # the same alpha per state is no bound per episode: that is why episodes are the unit
    assert np.mean(per_state_rates) > 3 * alpha


@pytest.mark.parametrize("statistic", [WindowMean(4), Cusum(0.3)], ids=["window", "cusum"])
def test_online_monitor_matches_the_offline_statistic_across_episode_resets(statistic):
    model = _cartpole_model()
    score = CallableScore(lambda s: s[:, 0], "synthetic")
    rng = np.random.default_rng(3)
    guard = SequentialGuard.from_episode_scores(model, score, _ar1_episodes(rng, 20, 30), 0.1, statistic)
    monitor = guard.monitor(n_envs=2)
    streams = [rng.normal(size=(25, 4)) for _ in range(2)]  # two envs, the second restarting at step 10
    monitor.reset()
    online = []
    for t in range(25):
        if t == 10:
            monitor.reset(np.array([False, True]))
        online.append(monitor.step(np.stack([streams[0][t], streams[1][t]])).statistics)
    online = np.array(online)
    np.testing.assert_allclose(online[:, 0], statistic.path(streams[0][:, 0]), rtol=1e-12)
    np.testing.assert_allclose(online[10:, 1], statistic.path(streams[1][10:, 0]), rtol=1e-12)


# ------------------------------------------------------------------------------ detection


def test_an_abrupt_jump_in_a_scripted_score_stream_is_flagged_within_the_window():
    model, window = _cartpole_model(), 5
    score = CallableScore(lambda s: s[:, 0], "scripted")
    rng = np.random.default_rng(4)
    guard = SequentialGuard.from_episode_scores(model, score, [rng.normal(size=60) for _ in range(30)], 0.05,
                                                WindowMean(window))
    for _ in range(20):
        change = int(rng.integers(10, 40))
        stream = rng.normal(size=60)
        stream[change + 1:] += 8.0  # s_{change+1} is the first state after the change
        flags = guard.alarms(stream)
        delay = np.flatnonzero(flags[change + 1:])[0] + 1
        assert 1 <= delay <= window


def test_a_large_mid_episode_physics_change_is_flagged_within_a_few_steps(tiny_models, id_episodes):
    """Gravity turning upward at step 15 of a real HalfCheetah episode; the guard reads GuardWrapper's info."""
    model = tiny_models["masksembles"].model
    score = make_score(model, "mahalanobis_obs", fit_states=np.concatenate(id_episodes[:6]))
    guard = SequentialGuard(model, score, id_episodes[6:16], alpha=0.1, statistic=WindowMean(3))
    config = PerturbationConfig(ENV, gravity=(0.0, 0.0, 9.81), outside_ranges=True)
    change = 15
    for seed in range(3):
        env = GuardWrapper(MidEpisodeShift(ENV, config, change), guard)
        obs, info = env.reset(seed=100 + seed)
        flags = [info["guard_flag"]]
        for t in range(30):
            obs, _, _, _, info = env.step(model.predict(obs, deterministic=True)[0])
            flags.append(info["guard_flag"])
            assert info["perturbed"] == (t >= change)
        env.close()
        delay = np.flatnonzero(flags[change + 1:])[0] + 1
        assert delay <= 6, f"seed {seed}: first alarm {delay} steps after the change"


def test_mid_episode_shift_keeps_the_robot_state_and_changes_only_the_physics():
    config = PerturbationConfig(ENV, geometry_scales={"bthigh": 2.0, "fthigh": 2.0})
    shifted, plain = MidEpisodeShift(ENV, config, 5), MidEpisodeShift(ENV)
    a, _ = shifted.reset(seed=1)
    b, _ = plain.reset(seed=1)
    actions = np.random.default_rng(0).uniform(-1, 1, (10, 6))
    diffs = []
    for action in actions:
        a, *_ = shifted.step(action)
        b, *_ = plain.step(action)
        diffs.append(np.abs(a - b).max())
    assert max(diffs[:5]) == 0.0  # identical until the change
    assert min(diffs[6:]) > 1e-3  # then the longer legs move differently


# ------------------------------------------------------------------------------- wrappers


class _ActionLog(gym.Wrapper):
    def __init__(self, env: gym.Env, log: list) -> None:
        super().__init__(env)
        self.log = log

    def step(self, action):
        self.log.append(np.array(action, copy=True))
        return self.env.step(action)


def _venv(log: list | None = None, guard: Guard | None = None) -> DummyVecEnv:
    """One 20-step HalfCheetah, seeded, optionally guarded and logging the actions it receives."""

    def make() -> gym.Env:
        env = Monitor(make_single_env(ENV, max_episode_steps=20))
        if guard is not None:
            env = GuardWrapper(env, guard)
        return env if log is None else _ActionLog(env, log)

    venv = DummyVecEnv([make])
    venv.seed(0)
    return venv


def test_guard_wrapper_reports_score_and_flag_under_evaluate_policy_with_a_ppo_load_model(tiny_repo, id_episodes):
    model = PPO.load(tiny_repo / "results/tiny/checkpoints" / ENV / "masksembles/seed0/model.zip", device="cpu")
    guard = Guard(model, "value_std", np.stack([e[5] for e in id_episodes[6:]]), alpha=0.1)
    infos = []
    _, lengths = evaluate_policy(model, _venv(guard=guard), n_eval_episodes=2, return_episode_rewards=True,
                                       callback=lambda local, _: infos.append(local["info"]))
    assert lengths == [20, 20] and len(infos) == 40
    for info in infos:
        assert {"guard_score", "guard_statistic", "guard_flag", "guard_threshold"} <= set(info)
        assert info["guard_flag"] == (info["guard_score"] > guard.threshold)


def test_guarded_policy_acts_with_the_fallback_while_flagged_and_calls_back(tiny_models):
    model = tiny_models["masksembles"].model
    always = Guard.from_scores(model, CallableScore(lambda s: np.ones(len(s)), "always"), np.zeros(9), alpha=0.1)
    log: list = []
    guarded = GuardedPolicy(model, always, fallback="zero")
    evaluate_policy(guarded, _venv(log), n_eval_episodes=1, deterministic=True)
    assert len(log) == 20 and all(np.all(a == 0) for a in log)
    assert guarded.flagged_steps == guarded.steps == 20

    alarms, log_plain, log_watch = [], [], []
    evaluate_policy(model, _venv(log_plain), n_eval_episodes=1, deterministic=True)
    watcher = GuardedPolicy(model, always, fallback=None, on_alarm=alarms.append)
    evaluate_policy(watcher, _venv(log_watch), n_eval_episodes=1, deterministic=True)
    np.testing.assert_array_equal(np.array(log_plain), np.array(log_watch))  # fallback None: the agent still acts
    assert len(alarms) == 20 and [a.onset for a in alarms] == [True] + [False] * 19
    assert [a.step for a in alarms] == list(range(20))


def test_a_silent_guard_does_not_change_a_sampling_mc_agent():
    """MC Dropout scores draw masks; the guard draws them from its own RNG, so sampled actions stay the same."""
    model = make_agent("ppo", "mc_dropout", ENV, 0)
    silent = Guard.from_scores(model, "value_std", np.full(9, 1e9), alpha=0.1)
    results = []
    for agent in (model, GuardedPolicy(model, silent)):
        th.manual_seed(0)
        log: list = []
        evaluate_policy(agent, _venv(log), n_eval_episodes=1, deterministic=False)
        results.append(np.array(log))
    np.testing.assert_array_equal(results[0], results[1])


def test_vecnormalize_agents_are_scored_on_what_the_policy_sees():
    model = make_agent("ppo", "baseline", "Walker2d-v5", 0)  # the paper's Walker2d normalizes observations
    normalizer = model.get_vec_normalize_env()
    normalizer.obs_rms.mean[:] = 3.0  # statistics as if trained: normalized observations differ from raw ones
    score = CallableScore(lambda s: np.abs(s).max(axis=1), "max_abs")
    guard = Guard.from_scores(model, score, np.linspace(0, 5, 20), alpha=0.1)
    with pytest.raises(ValueError, match="VecNormalize"):
        GuardWrapper(make_single_env("Walker2d-v5"), guard)
    env = GuardWrapper(make_single_env("Walker2d-v5"), guard, vecnormalize=normalizer)
    obs, info = env.reset(seed=0)
    assert info["guard_score"] == pytest.approx(score(normalizer.normalize_obs(obs[None]))[0])
    assert info["guard_score"] != pytest.approx(score(obs[None])[0])


# ---------------------------------------------------------------------------- persistence


def test_save_and_load_round_trip_with_the_models_folder(tiny_models, id_episodes, tmp_path):
    ckpt = tiny_models["masksembles"]
    model = ckpt.model
    fit = np.concatenate(id_episodes[:6])
    window = SequentialGuard(model, make_score(model, "knn_features", fit_states=fit), id_episodes[6:16], 0.1,
                             WindowMean(4))
    state = Guard(model, "value_std", np.stack([e[7] for e in id_episodes[6:]]), 0.1, confidence=0.8)
    combined_score = CombinedScore([make_score(model, "value_std"), make_score(model, "mahalanobis_obs", fit_states=fit)],
                                   reference_states=np.concatenate(id_episodes[20:22]))
    combined = SequentialGuard(model, combined_score, id_episodes[6:16], 0.1, Cusum(0.5))
    for guard in (window, state, combined):
        path = guard.save(tmp_path)
        assert path.parent == tmp_path / "guards" and (path / "guard.json").is_file()
        loaded = Guard.load(tmp_path, PPO.load(ckpt.folder / "model.zip", device="cpu"), key=path.name)
        assert type(loaded) is type(guard)
        assert (loaded.threshold, loaded.alpha, loaded.confidence, loaded.score.name, loaded.statistic) == \
               (guard.threshold, guard.alpha, guard.confidence, guard.score.name, guard.statistic)
        np.testing.assert_array_equal(loaded.calibration_scores, guard.calibration_scores)
        np.testing.assert_array_equal(loaded.score(id_episodes[23]), guard.score(id_episodes[23]))
        meta = json.loads((path / "guard.json").read_text())
        assert meta["versions"]["stable-baselines3"] and meta["model"]["method"] == "masksembles"

    with pytest.raises(FileNotFoundError, match="pass key="):
        Guard.load(tmp_path, model)
    with pytest.raises(ValueError, match="calibrated for a PPO masksembles"):
        Guard.load(tmp_path, tiny_models["baseline"].model, key=state.key)
    with pytest.raises(ValueError, match="calibrated for the score 'value_std', not 'policy_std'"):
        Guard.load(tmp_path, model, key=state.key, score="policy_std")


def test_a_callable_score_is_passed_again_on_load_and_a_failed_save_keeps_the_old_guard(tmp_path, monkeypatch):
    model = _cartpole_model()
    score = CallableScore(lambda s: s[:, 0], "pole_x")
    guard = Guard.from_scores(model, score, np.arange(20.0), 0.1)
    guard.save(tmp_path)
    with pytest.raises(ValueError, match="pass the same function again"):
        Guard.load(tmp_path, model)
    assert Guard.load(tmp_path, model, score=score).threshold == guard.threshold

    from paper_lib.guard import core

    def crash(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(core, "write_json_atomic", crash)
    with pytest.raises(OSError):
        Guard.from_scores(model, score, np.arange(50.0), 0.1).save(tmp_path)
    monkeypatch.undo()
    assert Guard.load(tmp_path, model, score=score).threshold == guard.threshold  # the old guard, whole
    assert [p.name for p in (tmp_path / "guards").iterdir()] == [guard.key]


# ----------------------------------------------------------------------------- bad inputs


@pytest.mark.parametrize("alpha", [0, 1, 1.5, -0.1, float("nan"), True, "0.1"])
def test_alpha_outside_zero_one_is_one_clear_error(alpha):
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        Guard.from_scores(_cartpole_model(), CallableScore(lambda s: s[:, 0], "x"), np.arange(100.0), alpha)


def test_too_few_calibration_units_name_the_fix():
    model, score = _cartpole_model(), CallableScore(lambda s: s[:, 0], "x")
    with pytest.raises(ValueError, match=r"needs at least 19 calibration states .* raise alpha to at least 0\.0909"):
        Guard.from_scores(model, score, np.arange(10.0), 0.05)
    with pytest.raises(ValueError, match="needs at least 9 calibration episodes"):
        SequentialGuard.from_episode_scores(model, score, [np.zeros(5)] * 5, 0.1)
    with pytest.raises(ValueError, match="needs at least 19 calibration episodes"):
        SequentialGuard(model, score, [np.zeros((5, 4))] * 3, 0.05)  # checked before anything is scored


def test_other_bad_inputs_are_one_clear_error(tiny_models, id_episodes):
    model = tiny_models["masksembles"].model
    fit = np.concatenate(id_episodes[:4])
    detector = make_score(model, "knn_obs", fit_states=fit)
    with pytest.raises(ValueError, match="were used to fit the score 'knn_obs'"):
        Guard(model, detector, fit[:40], 0.1)
    with pytest.raises(ValueError, match="needs ensemble members, but this policy has none"):
        Guard(tiny_models["baseline"].model, "value_std", fit[:40], 0.1)
    with pytest.raises(ValueError, match="is a detector and must be fitted"):
        make_score(model, "mahalanobis_obs")
    with pytest.raises(ValueError, match="unknown score 'surprise'"):
        make_score(model, "surprise")
    with pytest.raises(ValueError, match="one array of per-step scores"):
        SequentialGuard.from_episode_scores(model, detector, np.zeros(50), 0.1)
    with pytest.raises(ValueError, match="calibration_episodes must be a list"):
        SequentialGuard(model, detector, fit, 0.1)
    with pytest.raises(ValueError, match="window=0"):
        WindowMean(0)
    with pytest.raises(ValueError, match="calibration scores hold NaN"):
        Guard.from_scores(model, detector, np.array([1.0, np.nan] * 10), 0.1)
    with pytest.raises(ValueError, match="one score per state"):
        Guard(model, CallableScore(lambda s: np.zeros(3), "bad"), fit[:40], 0.1)
    with pytest.raises(ValueError, match="fallback='zero' needs continuous"):
        GuardedPolicy(_cartpole_model(), Guard.from_scores(_cartpole_model(), CallableScore(lambda s: s[:, 0], "x"),
                                                           np.arange(20.0), 0.1))
    with pytest.raises(ValueError, match="at least two Score objects"):
        CombinedScore([detector], fit)


def test_bad_guard_settings_are_one_clear_error():
    good = TEST_GUARD
    assert parse_settings(good, "tiny", "guard").calibration_episodes == 6
    with pytest.raises(ValueError, match="no mapping for the active profile 'cpu'"):
        parse_settings(good, "cpu", "guard")
    with pytest.raises(ValueError, match=r"alpha=0.05 needs calibration_episodes >= 19"):
        parse_settings({**good, "budgets": {"tiny": {**good["budgets"]["tiny"], "alpha": 0.05}}}, "tiny", "guard")
    with pytest.raises(ValueError, match="unknown key"):
        parse_settings({**good, "alpah": 0.1}, "tiny", "guard")
    confident = {**good, "confidence": 0.9}
    with pytest.raises(ValueError, match=r"alpha=0.2 at confidence=0.9 needs calibration_episodes >= 11"):
        parse_settings(confident, "tiny", "guard")
    more = {**confident, "budgets": {"tiny": {**good["budgets"]["tiny"], "calibration_episodes": 11}}}
    assert parse_settings(more, "tiny", "guard").confidence == 0.9 and parse_settings(good, "tiny", "guard").confidence is None
    with pytest.raises(ValueError, match="confidence=2"):
        parse_settings({**more, "confidence": 2}, "tiny", "guard")
    with pytest.raises(ValueError, match="change_steps"):
        parse_settings({**good, "budgets": {"tiny": {**good["budgets"]["tiny"], "change_steps": [5, 40]}}},
                       "tiny", "guard")


def test_a_guard_budget_can_cover_some_seeds_only():
    good = TEST_GUARD
    every = parse_settings(good, "tiny", "guard")
    assert every.seeds is None and every.covers(0) and every.covers(2)
    first = parse_settings({**good, "budgets": {"tiny": {**good["budgets"]["tiny"], "seeds": [0]}}}, "tiny", "guard")
    assert first.covers(0) and not first.covers(1) and "seed(s) 0 only" in first.caption()
    for bad in ([], [-1], "0", [True]):
        with pytest.raises(ValueError, match="seeds must be a non-empty list"):
            parse_settings({**good, "budgets": {"tiny": {**good["budgets"]["tiny"], "seeds": bad}}}, "tiny", "guard")


# ------------------------------------------------------------------------------- notebook


def test_notebook_8_runs_at_the_tiny_budget(tiny_repo, tmp_path):
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg"}
    out = tmp_path / "08_guard.ipynb"
    done = subprocess.run([str(BIN / "python"), "-m", "paper_lib.pipeline.notebook_run",  # as its DVC stage runs it
                           str(REPO / "notebooks/08_guard.ipynb"), str(out), "-p", "params_file",
                           str(tiny_repo / "params.yaml")], cwd=REPO, env=env, capture_output=True, text=True,
                          check=False)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    results = tiny_repo / "results" / "tiny"
    for stem in ("guard_detection", "guard_returns"):
        for suffix in (".csv", ".md", ".tex"):
            assert (results / "tables" / "guard" / f"{stem}{suffix}").stat().st_size > 0
        assert "profile 'tiny'" in (results / "tables" / "guard" / f"{stem}.md").read_text().splitlines()[0]
    for stem in ("guard_false_alarms", "guard_delay", "guard_trace"):
        for suffix in (".png", ".pdf"):
            assert (results / "figures" / "guard" / f"{stem}{suffix}").stat().st_size > 0
    import pandas as pd

    table = pd.read_csv(results / "tables" / "guard" / "guard_detection.csv")
    assert set(table.method) == {"baseline", "masksembles"} and set(table.guard) == {"state", "window", "cusum"}
    assert {"value_std", "mahalanobis_obs", "knn_features"} <= set(table.score)
    assert not table.query("method == 'baseline'").score.isin(["value_std", "policy_std", "policy_js"]).any()
    saved = list((results / "guards" / ENV / "masksembles" / "seed0" / "guards").iterdir())
    assert len(saved) == 2 and all((p / "guard.json").is_file() for p in saved)  # the two fallback guards
    text = json.loads(out.read_text())
    summary = [o for c in text["cells"] for o in c.get("outputs", []) if "text/markdown" in o.get("data", {})]
    assert summary and "ID test episodes" in "".join(summary[-1]["data"]["text/markdown"])


# ------------------------------------------------------------------------------- the per-run cache


def test_a_run_is_replayed_only_when_its_inputs_change(tiny_repo, tiny_models, tmp_path):
    import dataclasses

    from paper_lib.guard.cache import FOLDER, TABLES, cached_experiment, fingerprint

    _, settings = load_settings(tiny_repo / "params.yaml")
    mode, run = ActionMode(deterministic=False), tiny_models["masksembles"]
    first, cached = cached_experiment(run, settings, mode, 0, tmp_path)
    assert not cached and first.guards
    stored = {name: (tmp_path / FOLDER / f"{name}.pkl").read_bytes() for name in TABLES}
    again, cached = cached_experiment(run, settings, mode, 0, tmp_path)
    assert cached and not again.guards and again.n_redrawn == first.n_redrawn
    for name in TABLES:
        pd.testing.assert_frame_equal(getattr(again, name), getattr(first, name))
    (tmp_path / FOLDER / "fingerprint.json").unlink()  # a replay of the same inputs writes the same bytes
    assert not cached_experiment(run, settings, mode, 0, tmp_path)[1]
    assert stored == {name: (tmp_path / FOLDER / f"{name}.pkl").read_bytes() for name in TABLES}
    key = fingerprint(run, settings, mode, 0)
    assert key != fingerprint(run, dataclasses.replace(settings, alpha=0.1), mode, 0)
    assert key != fingerprint(run, settings, ActionMode(deterministic=True), 0)
    assert key != fingerprint(run, settings, mode, 1)
    assert key != fingerprint(tiny_models["baseline"], settings, mode, 0)


def test_the_fingerprint_covers_every_module_a_guard_experiment_runs(tiny_repo):
    # a fresh interpreter: which paper_lib modules does a real (tiny) guard experiment import?
    script = f"""
import sys
from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.guard.cache import cached_experiment
from paper_lib.guard.settings import load_settings
from paper_lib.ood.collect import ActionMode
cfg, settings = load_settings({str(tiny_repo / 'params.yaml')!r})
run = load_checkpoint(cfg.checkpoint_dir({ENV!r}, 'masksembles', 0))
cached_experiment(run, settings, ActionMode(deterministic=False), 0, {str(tiny_repo / 'fingerprint_check')!r})
print(' '.join(sorted(m for m in sys.modules if m.startswith('paper_lib'))))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    from paper_lib.guard.cache import SOURCE_MODULES

    assert set(done.stdout.split()) <= set(SOURCE_MODULES), set(done.stdout.split()) - set(SOURCE_MODULES)


def test_detection_table_reports_the_rate_each_guard_bounds():
    """State guard: a random state of a random episode (episode-weighted), not steps pooled; window: episodes."""
    from paper_lib.guard.report import detection_table

    base = {"env": "Walker2d-v5", "method": "masksembles", "score": "value_std", "alpha": 0.05, "n_calibration": 100,
            "confidence": 0.9, "episode_kind": "id", "delay": np.nan, "alarm_before_change": False,
            "reached_change": False}
    episodes = pd.DataFrame([
        {**base, "guard": "state", "steps": 100, "flagged_steps": 10, "any_alarm": True},
        {**base, "guard": "state", "steps": 10, "flagged_steps": 5, "any_alarm": True},  # a short episode (a fall)
        {**base, "guard": "window", "steps": 100, "flagged_steps": 3, "any_alarm": True},
        {**base, "guard": "window", "steps": 10, "flagged_steps": 0, "any_alarm": False},
    ])
    table = detection_table(episodes, ["masksembles"]).set_index("guard")
    assert table.loc["state", "id_false_alarm_rate"] == pytest.approx((0.1 + 0.5) / 2)
    assert table.loc["state", "id_alarms_per_1000_steps"] == pytest.approx(1000 * 15 / 110)
    assert table.loc["window", "id_false_alarm_rate"] == pytest.approx(0.5)
    assert table.loc["state", "expected_rate"] == pytest.approx(2 / 101)  # k = 99 of n = 100 at confidence 0.9


def test_false_alarm_figure_names_each_score_once_per_row_in_one_order():
    """The three guard panels of an env share their rows: same score order, labels only on the left panel."""
    from paper_lib.guard.report import false_alarm_figure

    rows = [{"env": "Walker2d-v5", "method": method, "score": score, "guard": guard, "alpha": 0.05,
             "id_false_alarm_rate": 0.01}
            for guard in ("cusum", "state", "window") for method in ("baseline", "masksembles")
            for score in (["value_std", "knn_obs"] if guard == "cusum" else ["knn_obs", "value_std"])]
    fig = false_alarm_figure(pd.DataFrame(rows))
    state, window, cusum = fig.axes[:3]
    fig.canvas.draw()

    def row_names(ax) -> list[str]:  # the score of each row, shown or not
        return [tick.label1.get_text() for tick in ax.yaxis.get_major_ticks()]

    assert row_names(state) == ["value_std", "knn_obs"]  # first appearance in the table (here the cusum rows)
    assert [t.get_text() for t in state.get_yticklabels()] == ["value_std", "knn_obs"]
    for ax in (window, cusum):
        assert row_names(ax) == ["value_std", "knn_obs"]
        assert ax.get_yticklabels() == []  # hidden: the left panel names the rows
