"""Issue 41, library entry points: each bad input is one clear error before any work, each legitimate one works.

Every test uses real objects (make_agent on CartPole-v1, real SB3 zips) and fails if its check is removed.
"""

from __future__ import annotations

import copy
import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.env_util import make_vec_env

from paper_lib import make_agent, make_env, member_outputs, paper_hyperparameters, uncertainty
from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.agents.training import train_run
from paper_lib.methods.groups import MemberGroupVecEnv, tag_observation
from paper_lib.methods.independent import assemble_ensemble
from paper_lib.methods.policy import MemberActorCriticPolicy
from paper_lib.pipeline.evaluate_agent import load_agent

TINY = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}
#: A CUDA device index no machine has: one past the last (cuda:0 where there is no GPU).
ABSENT_CUDA = f"cuda:{th.cuda.device_count()}"


@pytest.fixture(scope="module")
def member_agent():
    return make_agent("ppo", "masksembles", "CartPole-v1", 0, n_envs=4, overrides=TINY)


@pytest.fixture(scope="module")
def states() -> np.ndarray:
    return np.random.default_rng(0).normal(0.0, 0.1, (3, 4)).astype(np.float32)


# --- 1. numpy integer seeds ------------------------------------------------------------------------

def test_numpy_integer_seeds_work_like_ints():
    model = make_agent("ppo", "ensemble", "CartPole-v1", np.int64(3), n_envs=4, overrides=TINY)
    assert type(model.paper_lib_config["seed"]) is int and json.dumps(model.paper_lib_config["seed"]) == "3"
    first, second = make_env("CartPole-v1", 2, np.int64(5)), make_env("CartPole-v1", 2, 5)
    np.testing.assert_array_equal(first.reset(), second.reset())


def test_train_run_takes_a_numpy_seed(tmp_path):
    out = train_run("CartPole-v1", "ensemble", np.int64(0), tmp_path / "ckpt", total_timesteps=64,
                    agent_kwargs={"overrides": TINY, "n_envs": 4}, resume=False)
    assert json.loads((out / "config.json").read_text())["seed"] == 0


@pytest.mark.parametrize("seed", [True, 1.0, "0", -1])
def test_seeds_that_are_not_integers_are_refused(seed):
    with pytest.raises(ValueError, match=r"seed must be an integer"):
        make_agent("ppo", "ensemble", "CartPole-v1", seed, overrides=TINY)
    with pytest.raises(ValueError, match=r"make_env: seed must be an integer >= 0, got"):
        make_env("CartPole-v1", 1, seed)


# --- 2. batch_size of the uncertainty calls ----------------------------------------------------------

@pytest.mark.parametrize("batch_size", [0, -1, True, 2.0])
def test_batch_size_below_one_is_refused(member_agent, states, batch_size):
    for call in (uncertainty, member_outputs):
        with pytest.raises(ValueError, match=r"batch_size must be a positive integer .*got "):
            call(member_agent.policy, states, batch_size=batch_size)
    assert uncertainty(member_agent.policy, states, batch_size=np.int64(2))["value_std"].shape == (3,)


# --- 3. a zip of an algorithm paper_lib does not load ------------------------------------------------

@pytest.fixture(scope="module")
def dqn_zip(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("dqn") / "model.zip"
    DQN("MlpPolicy", "CartPole-v1", buffer_size=64, learning_starts=0, seed=0).save(path)
    return path


FOREIGN = r"holds a model paper_lib cannot load, got DQN; paper_lib loads A2C, PPO, TRPO models"


@pytest.mark.parametrize("algo", ["a2c", "ppo"])
def test_checkpoint_of_another_algorithm_names_it(tmp_path, dqn_zip, algo):
    (tmp_path / "model.zip").write_bytes(dqn_zip.read_bytes())
    (tmp_path / "config.json").write_text(json.dumps({"algo": algo, "env_id": "CartPole-v1", "method": "baseline",
                                                      "seed": 0, "normalize_obs": False}))
    with pytest.raises(ValueError, match=FOREIGN):
        load_checkpoint(tmp_path)


@pytest.mark.parametrize("algo", [None, "a2c", "ppo"])
def test_load_agent_names_the_algorithm_of_the_zip(dqn_zip, algo):
    with pytest.raises(ValueError, match=FOREIGN):
        load_agent(dqn_zip, algo)


# --- 4. set_inference's member ----------------------------------------------------------------------

@pytest.mark.parametrize("mode,member,match", [
    ("vote", 2, r"inference mode 'vote' combines all members and takes no member, got member=2"),
    ("average", 0, r"inference mode 'average' combines all members and takes no member, got member=0"),
    ("single", 1.7, r"inference member must be an integer index in \[0, 3\], got 1\.7"),
    ("single", True, r"inference member must be an integer index in \[0, 3\], got True"),
    ("single", 4, r"inference_member=4 is not in \[0, 3\]"),
    ("single", -1, r"inference_member=-1 is not in \[0, 3\]"),
])
def test_set_inference_refuses_a_member_it_would_ignore_or_misuse(member_agent, mode, member, match):
    policy = member_agent.policy
    policy.set_inference("vote")
    with pytest.raises(ValueError, match=match):
        policy.set_inference(mode, member)
    assert policy.inference == ("vote", None)  # nothing was changed
    policy.set_inference("single", np.int64(2))
    assert policy.inference == ("single", 2) and type(policy.inference[1]) is int
    policy.set_inference("vote")


# --- 5. env groups made for another k ---------------------------------------------------------------

def test_make_agent_refuses_env_groups_for_another_k():
    with pytest.raises(ValueError, match=r"MemberGroupVecEnv for 2 members, got n_members=4"):
        make_agent("ppo", "masksembles", "CartPole-v1", 0, n_members=4, n_envs=4, overrides=TINY,
                   env=MemberGroupVecEnv(make_env("CartPole-v1", 4, 0), 2))
    make_agent("ppo", "masksembles", "CartPole-v1", 0, n_members=4, n_envs=4, overrides=TINY,
               env=MemberGroupVecEnv(make_env("CartPole-v1", 4, 0), 4))


def test_training_refuses_env_groups_for_another_k():
    """Built without make_agent: the first truncated episode's bootstrap refuses the wrong groups."""
    venv = make_vec_env("CartPole-v1", 4, seed=0, env_kwargs={"max_episode_steps": 3})
    model = PPO(MemberActorCriticPolicy, MemberGroupVecEnv(venv, 2), n_steps=8, batch_size=32, n_epochs=1,
                policy_kwargs={"method": "ensemble", "n_members": 4}, seed=0)
    with pytest.raises(ValueError, match=r"splits its envs into 2 member groups, got a policy with k=4 members"):
        model.learn(32)


def test_a_terminal_observation_tagged_for_another_k_is_refused(member_agent, states):
    policy = member_agent.policy
    with pytest.raises(ValueError, match=r"2 member groups, got a policy with k=4"):
        policy.predict_values(policy.obs_to_tensor(tag_observation(states[0], 1, 2))[0])
    assert policy.predict_values(policy.obs_to_tensor(tag_observation(states[0], 1, 4))[0]).shape == (1, 1)


# --- 6. non-finite observations ----------------------------------------------------------------------

def _bad_states(states: np.ndarray) -> dict[str, np.ndarray]:
    nan = states.copy()
    nan[0, 1], nan[2, 3] = np.nan, np.inf
    overflow = states.astype(np.float64)
    overflow[1, 0] = 1e39  # finite in float64, inf as the float32 the network computes in
    return {"nan": nan, "overflow": overflow}


@pytest.mark.parametrize("kind,rows", [("nan", 2), ("overflow", 1)])
def test_non_finite_observations_are_refused(member_agent, states, kind, rows):
    obs = _bad_states(states)[kind]
    match = rf"observations hold NaN or inf in {rows} of 3 states"
    for call in (member_agent.predict, lambda o: member_agent.predict(o.tolist()),
                 lambda o: uncertainty(member_agent.policy, o), lambda o: member_outputs(member_agent.policy, o)):
        with pytest.raises(ValueError, match=match):
            call(obs)
    with pytest.raises(ValueError, match=r"NaN or inf in 1 of 1 states"):
        member_agent.predict(obs[0 if kind == "nan" else 1])


def test_integer_observations_skip_the_finiteness_check(member_agent, states):
    actions, _ = member_agent.predict(np.zeros((3, 4), dtype=np.int64), deterministic=True)
    assert actions.shape == (3,)
    assert member_agent.predict(states, deterministic=True)[0].shape == (3,)


# --- 7. an ensemble of one agent twice ----------------------------------------------------------------

def test_an_ensemble_of_identical_members_is_refused(states):
    agent = make_agent("ppo", "baseline", "CartPole-v1", 0, overrides=TINY)
    other = make_agent("ppo", "baseline", "CartPole-v1", 1, overrides=TINY)
    for members in ([agent, agent], [agent, other, copy.deepcopy(agent)]):
        with pytest.raises(ValueError, match=r"members 0 and \d have identical parameters, got the same agent twice"):
            assemble_ensemble(members)
    assert uncertainty(assemble_ensemble([agent, other]).policy, states)["value_std"].min() > 0


# --- 8. an explicit device that is not there ------------------------------------------------------------

def test_an_absent_device_is_refused(tmp_path, dqn_zip):
    with pytest.raises(ValueError, match=rf"make_agent: device '{ABSENT_CUDA}' is not available on this machine"):
        make_agent("ppo", "ensemble", "CartPole-v1", 0, overrides=TINY, device=ABSENT_CUDA)
    with pytest.raises(ValueError, match=rf"device '{ABSENT_CUDA}' is not available"):
        train_run("CartPole-v1", "ensemble", 0, tmp_path / "ckpt", total_timesteps=64,
                  agent_kwargs={"overrides": TINY, "device": ABSENT_CUDA})
    assert not (tmp_path / "ckpt").exists()
    with pytest.raises(ValueError, match=r"device must be a torch device such as 'cpu', 'cuda' or 'auto', got 'gpu'"):
        make_agent("ppo", "ensemble", "CartPole-v1", 0, overrides=TINY, device="gpu")
    with pytest.raises(ValueError, match=rf"load_agent: device '{ABSENT_CUDA}' is not available"):
        load_agent(dqn_zip, device=ABSENT_CUDA)


@pytest.mark.skipif(th.cuda.is_available(), reason="this machine has CUDA")
def test_cuda_without_a_gpu_is_refused():
    with pytest.raises(ValueError, match=r"device 'cuda' is not available on this machine"):
        make_agent("ppo", "ensemble", "CartPole-v1", 0, overrides=TINY, device="cuda")


def test_auto_and_cpu_keep_working():
    assert make_agent("ppo", "ensemble", "CartPole-v1", 0, overrides=TINY, device="cpu").device.type == "cpu"
    expected = "cuda" if th.cuda.is_available() else "cpu"
    assert make_agent("ppo", "ensemble", "CartPole-v1", 0, overrides=TINY, device="auto").device.type == expected


# --- 9. issue 71: the doors that were open, their legitimate uses ------------------------------------

def test_uncertainty_takes_the_model_as_its_policy(member_agent, states):
    """`uncertainty(model, obs)` means `model.policy`: the same scores, not {} or an AttributeError."""
    by_model, by_policy = (uncertainty(m, states, seed=3) for m in (member_agent, member_agent.policy))
    assert by_model.keys() == by_policy.keys() and by_model
    for name in by_model:
        np.testing.assert_array_equal(by_model[name], by_policy[name])
    assert member_outputs(member_agent, states, seed=np.int64(3)).values.shape == (4, 3)


def test_raw_atari_frames_are_scored_and_scaled_ones_are_refused():
    model = make_agent("ppo", "baseline", "SeaquestNoFrameskip-v4", 0, n_envs=2, overrides=TINY)
    frames = np.random.default_rng(0).integers(0, 256, (2, 84, 84, 4), dtype=np.uint8)
    assert uncertainty(model, frames)["entropy"].shape == (2,)
    assert uncertainty(model, frames.astype(np.int64))["entropy"].shape == (2,)  # any integer dtype in range
    with pytest.raises(ValueError, match=r"observations are float64 but .* uint8 frames in \[0, 255\]"):
        uncertainty(model, frames / 255.0)


def test_make_agent_takes_an_env_of_its_id_and_refuses_another(states):
    make_agent("ppo", "baseline", "CartPole-v1", 0, n_envs=4, overrides=TINY, env=make_env("CartPole-v1", 4, 0))
    with pytest.raises(ValueError, match=r"the given env runs Acrobot-v1 but env_id is 'CartPole-v1'"):
        make_agent("ppo", "baseline", "CartPole-v1", 0, n_envs=4, overrides=TINY, env=make_env("Acrobot-v1", 4, 0))


def test_a_guard_goes_with_a_copy_of_its_model_and_with_a_plain_predictor():
    from paper_lib.guard import CallableScore, Guard, GuardedPolicy

    model = make_agent("ppo", "baseline", "CartPole-v1", 0, overrides=TINY)
    guard = Guard.from_scores(model, CallableScore(lambda s: s[:, 0], "x"), np.arange(20.0), 0.1)
    GuardedPolicy(copy.deepcopy(model), guard, fallback=None)  # the same weights: the guard's calibration holds

    class Predictor:  # no weights to compare: the guard scores with its own model
        action_space, observation_space = model.action_space, model.observation_space

        def predict(self, obs, **kwargs):
            return np.zeros(len(obs), dtype=np.int64), None

    GuardedPolicy(Predictor(), guard, fallback=None)


def test_uncertainty_takes_one_measure_name_as_a_string(member_agent, states):
    """measures_wanted="value_std" is that measure, not its letters (which read as 'measure "v" is not available')."""
    one = uncertainty(member_agent, states, "value_std", seed=3)
    assert list(one) == ["value_std"]
    np.testing.assert_array_equal(one["value_std"], uncertainty(member_agent, states, ("value_std",), seed=3)["value_std"])


@pytest.mark.parametrize("damage", [
    ("guard.json", lambda b: b"not json {"),
    ("guard.json", lambda b: json.dumps({k: v for k, v in json.loads(b).items() if k != "threshold"}).encode()),
    ("guard.json", lambda b: b"[1, 2]"),
    ("arrays.npz", lambda b: b[: len(b) // 2]),
], ids=["garbage-json", "json-without-threshold", "json-list", "arrays-cut"])
def test_a_damaged_saved_guard_is_one_clear_error_and_stays_as_it_was(tmp_path, damage):
    from paper_lib.guard import CallableScore, Guard

    model = make_agent("ppo", "baseline", "CartPole-v1", 0, overrides=TINY)
    score = CallableScore(lambda s: s[:, 0], "x")
    folder = Guard.from_scores(model, score, np.arange(20.0), 0.1).save(tmp_path)
    assert Guard.load(tmp_path, model, score=score).threshold is not None  # whole, it loads
    name, damaged = damage
    (folder / name).write_bytes(damaged((folder / name).read_bytes()))
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(ValueError, match=rf"{name} .*the saved guard is damaged or incomplete; calibrate it again"):
        Guard.load(tmp_path, model, score=score)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_a_missing_atari_rom_is_one_error_naming_the_file_and_the_fix(tmp_path, monkeypatch):
    monkeypatch.setenv("ALE_ROMS_DIR", str(tmp_path))  # a ROM folder without seaquest.bin (ale-py's own is untouched)
    with pytest.raises(FileNotFoundError, match=r"ROM of SeaquestNoFrameskip-v4 \(seaquest.bin\) is not in .*reinstall"):
        make_env("SeaquestNoFrameskip-v4", 1, 0)
    monkeypatch.delenv("ALE_ROMS_DIR")
    make_env("SeaquestNoFrameskip-v4", 1, 0).close()


def test_saved_normalizers_record_their_env_and_old_ones_are_accepted_with_a_warning(tmp_path):
    from stable_baselines3.common.vec_env import VecNormalize

    from paper_lib.agents.envs import normalizer_env_id, save_normalizer
    from paper_lib.pipeline.evaluate_agent import load_vecnormalize

    save_normalizer(VecNormalize(make_env("HalfCheetah-v5", 1, 0)), tmp_path / "new.pkl", "HalfCheetah-v5")
    VecNormalize(make_env("HalfCheetah-v5", 1, 0)).save(str(tmp_path / "old.pkl"))  # before ids were recorded
    assert normalizer_env_id(load_vecnormalize(tmp_path / "new.pkl", "HalfCheetah-v5", 0)) == "HalfCheetah-v5"
    with pytest.warns(UserWarning, match=r"old\.pkl records no env id .* a normalizer of another env with "
                                         r"observations of the same shape would be applied without a word"):
        load_vecnormalize(tmp_path / "old.pkl", "HalfCheetah-v5", 0)


def test_training_records_the_env_of_its_normalizer(tmp_path):
    from paper_lib.agents.envs import normalizer_env_id

    hp = {**paper_hyperparameters("CartPole-v1"), "normalize_obs": True}
    out = train_run("CartPole-v1", "baseline", 0, tmp_path / "ckpt", total_timesteps=64,
                    agent_kwargs={"overrides": TINY, "n_envs": 4, "hyperparameters": hp}, resume=False)
    ckpt = load_checkpoint(out, "CartPole-v1", "baseline", 0)
    with open(ckpt.vecnormalize_path, "rb") as f:
        assert normalizer_env_id(pickle.load(f)) == "CartPole-v1"
