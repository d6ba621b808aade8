"""Training: the recipe reaches every member, runs resume after a kill, checkpoints swap atomically."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3 import PPO
from torch import nn

from paper_lib import make_agent, member_outputs
from paper_lib.agents.training import apply_hp_edits, resume_dir_for, train_run
from paper_lib.common import io
from paper_lib.common.io import atomic_dir, recover_dir
from paper_lib.methods.layers import MemberLinear

REPO = Path(__file__).resolve().parents[2]
TINY = {"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}}


def _member_linears(policy) -> list[MemberLinear]:
    return [m for m in policy.mlp_extractor.modules() if isinstance(m, MemberLinear)]


@pytest.mark.parametrize("method", ["masksembles", "ensemble", "mc_dropconnect"])
def test_member_policies_take_the_zoo_recipe_like_mlppolicy(method):
    """HalfCheetah's table entry: ReLU, log_std_init=-2, PyTorch default init (ortho_init=False)."""
    model = make_agent("ppo", method, "HalfCheetah-v5", 0)
    baseline = make_agent("ppo", "baseline", "HalfCheetah-v5", 0).policy
    policy = model.policy
    assert th.all(policy.log_std == -2.0) and th.all(baseline.log_std == -2.0)
    assert any(isinstance(m, nn.ReLU) for m in policy.mlp_extractor.modules())
    assert not any(isinstance(m, nn.Tanh) for m in policy.mlp_extractor.modules())
    for layer in _member_linears(policy):
        bound = 1 / math.sqrt(layer.d_in)
        w, b = layer.weight.detach(), layer.bias.detach()
        assert w.abs().max() <= bound and w.abs().max() > 0.9 * bound, "U(-1/sqrt(fan_in), 1/sqrt(fan_in))"
        assert b.abs().max() > 0, "PyTorch's default init draws the bias too (orthogonal init zeroes it)"
        if method == "ensemble":
            assert not th.equal(w[0], w[1]), "ensemble members start from different weights"
    first = baseline.mlp_extractor.policy_net[0]
    assert first.weight.abs().max() <= 1 / math.sqrt(first.in_features), "the baseline is initialized the same way"


def test_ortho_init_stays_sbs_default_where_the_table_says_so():
    """Ant's entry keeps SB3's defaults: orthogonal members (gain sqrt 2), zero bias, Tanh."""
    policy = make_agent("ppo", "ensemble", "Ant-v5", 0).policy
    assert th.all(policy.log_std == 0.0)
    hidden = _member_linears(policy)[0]
    w = hidden.weight.detach().transpose(1, 2)  # (k, out, in)
    for member in w:
        gram = member.T @ member if member.shape[0] >= member.shape[1] else member @ member.T
        assert th.allclose(gram, 2.0 * th.eye(gram.shape[0]), atol=1e-4)
    assert th.all(hidden.bias == 0)
    assert any(isinstance(m, nn.Tanh) for m in policy.mlp_extractor.modules())


def test_unknown_policy_setting_is_one_clear_error():
    from paper_lib.agents.factory import paper_hyperparameters

    hp = paper_hyperparameters("HalfCheetah-v5")
    hp["policy"]["activation_fn"] = "gelu"
    with pytest.raises(ValueError, match="activation_fn='gelu'; use one of"):
        make_agent("ppo", "masksembles", "HalfCheetah-v5", 0, hyperparameters=hp)
    with pytest.raises(ValueError, match="unknown setting 'dropout'"):
        apply_hp_edits(paper_hyperparameters("HalfCheetah-v5"), ["members.dropout=0.2"])
    edited = apply_hp_edits(paper_hyperparameters("HalfCheetah-v5"), ["members.dropout_p=0.2", "normalize_obs=true"])
    assert edited["members"]["dropout_p"] == 0.2 and edited["normalize_obs"] is True


def test_committed_checkpoint_holds_inference_weights_and_loads_with_plain_ppo(tmp_path):
    out = train_run("CartPole-v1", "masksembles", 0, tmp_path / "ckpt", total_timesteps=64, agent_kwargs=TINY)
    model = PPO.load(out / "model.zip", device="cpu")
    assert model.policy.optimizer.state_dict()["state"] == {}, "no optimizer moments in the committed file"
    resume = resume_dir_for(out)
    full = PPO.load(resume / "model.zip", device="cpu")
    assert full.policy.optimizer.state_dict()["state"], "the resume point keeps the optimizer state"
    obs = np.random.default_rng(0).normal(size=(8, 4)).astype(np.float32)
    ours, theirs = member_outputs(model.policy, obs), member_outputs(full.policy, obs)
    assert np.array_equal(ours.action_params, theirs.action_params) and np.array_equal(ours.values, theirs.values)


def test_reward_normalization_scales_training_rewards_only(tmp_path):
    """`normalize_reward` (the zoo's `normalize: true`) trains on scaled rewards; evaluation sees the env's own."""
    from paper_lib.agents.checkpoints import load_checkpoint
    from paper_lib.agents.factory import paper_hyperparameters

    hp = apply_hp_edits(paper_hyperparameters("Walker2d-v5"), ["normalize_reward=true"])
    model = make_agent("ppo", "baseline", "Walker2d-v5", 0, hyperparameters=hp, n_envs=2, **TINY)
    venv = model.get_vec_normalize_env()
    assert venv.norm_reward and venv.norm_obs and venv.gamma == hp["algo"]["gamma"]
    out = train_run("Walker2d-v5", "baseline", 0, tmp_path / "ckpt", total_timesteps=64,
                    agent_kwargs={**TINY, "hyperparameters": hp, "n_envs": 2})
    ckpt = load_checkpoint(out, "Walker2d-v5", "baseline", 0)
    assert ckpt.config["normalize_reward"] is True
    saved = ckpt.env(1, 0)
    assert saved.ret_rms.count > 1, "the return statistics were learned in training and saved"
    saved.reset()
    _, reward, _, _ = saved.step(np.zeros((1, *saved.action_space.shape), dtype=np.float32))
    raw = saved.get_original_reward()
    assert not saved.norm_reward and reward[0] == raw[0], "evaluation reports the env's own reward"
    off = apply_hp_edits(paper_hyperparameters("Walker2d-v5"), ["normalize_reward=false"])
    plain = make_agent("ppo", "baseline", "Walker2d-v5", 0, hyperparameters=off, n_envs=2, **TINY).get_vec_normalize_env()
    assert plain.norm_obs and not plain.norm_reward, "with the setting off, observations only (the printed recipe)"


def test_atari_checkpoints_store_float16_weights_and_load_as_float32(tmp_path):
    """Image policies are committed in float16 (half the size); PPO.load gives a float32 policy of the rounded weights."""
    from paper_lib.agents.checkpoints import load_checkpoint

    game = "SeaquestNoFrameskip-v4"
    tiny = {"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}, "n_envs": 4}
    out = train_run(game, "masksembles", 0, tmp_path / "ckpt", total_timesteps=64, agent_kwargs=tiny)
    ckpt = load_checkpoint(out, game, "masksembles", 0)
    assert ckpt.config["weights_dtype"] == "float16"
    full = PPO.load(resume_dir_for(out) / "model.zip", device="cpu")  # the float32 training state
    params = dict(ckpt.model.policy.named_parameters())
    for name, trained in full.policy.named_parameters():
        assert params[name].dtype == th.float32
        assert th.equal(params[name], trained.detach().half().float()), name
    obs = np.random.default_rng(0).integers(0, 255, size=(3, 84, 84, 4), dtype=np.uint8)
    ours, theirs = member_outputs(ckpt.model.policy, obs), member_outputs(full.policy, obs)
    np.testing.assert_allclose(ours.values, theirs.values, rtol=1e-2, atol=1e-3)
    float32_bytes = sum(4 * p.numel() for p in full.policy.parameters())
    assert (out / "model.zip").stat().st_size < 0.6 * float32_bytes, "about half of the float32 weights"
    mlp = train_run("CartPole-v1", "baseline", 0, tmp_path / "mlp", total_timesteps=64, agent_kwargs=TINY)
    assert load_checkpoint(mlp).config["weights_dtype"] == "float32"


def test_atomic_dir_keeps_the_old_folder_when_writing_fails(tmp_path):
    target = tmp_path / "ckpt"
    with atomic_dir(target) as tmp:
        (tmp / "a").write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_dir(target) as tmp:
            (tmp / "a").write_text("new")
            raise RuntimeError("killed")
    assert (target / "a").read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["ckpt"]
    with atomic_dir(target) as tmp:
        (tmp / "a").write_text("new")
    assert (target / "a").read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["ckpt"]
    # a swap interrupted between two renames (file systems without an atomic exchange): the swap marks the old
    # copy as its own before renaming it, and only a marked copy is ever put back
    io._mark(target)
    os.rename(target, tmp_path / ".ckpt.old")
    recover_dir(target)
    assert (target / "a").read_text() == "new"


def test_a_killed_run_resumes_from_its_last_resume_point(tmp_path):
    """kill -9 mid-training, run the same command again: it continues and finishes the budget."""
    out = tmp_path / "ckpt"
    cmd = [sys.executable, "-m", "paper_lib.agents.training", "CartPole-v1", "ensemble", "0", str(out),
           "--timesteps", "4096", "--resume-every", "256", "--device", "cpu"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    state = resume_dir_for(out) / "state.pkl"
    deadline = time.monotonic() + 120
    while not state.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert state.exists(), "a resume point was written before the kill"
    assert not out.exists(), "the killed run left no checkpoint"
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "resuming CartPole-v1 ensemble seed 0 from step" in done.stderr
    config = json.loads((out / "config.json").read_text())
    assert config["trained_timesteps"] == 4096 and config["resumed_from"] > 0 and config["device"] == "cpu"
    segments = config["segments"]
    assert [s["device"] for s in segments] == ["cpu", "cpu"], "where each stretch trained: before and after the kill"
    assert segments[0]["from_step"] == 0 and segments[-1]["to_step"] == 4096
    assert segments[0]["to_step"] == segments[1]["from_step"] == config["resumed_from"]
    assert {"platform", "cpu", "cpus", "simd"} <= set(config["machine"]), "the CPU, whose kernels set the last bits"
    curve = (out / "training_curve.csv").read_text().splitlines()
    steps = [int(line.split(",")[0]) for line in curve[1:]]
    assert steps == sorted(set(steps)) and steps[-1] == 4096, "one curve, no step counted twice"
    PPO.load(out / "model.zip", device="cpu")
    leftovers = [p.name for p in tmp_path.iterdir() if p.name not in ("ckpt", ".ckpt.resume")]
    assert leftovers == [], "no temporary folders remain"


def test_envs_in_subprocesses_train_the_same_agent(tmp_path):
    """`--env-processes` (SubprocVecEnv, for many-core GPU machines) changes speed, not the transitions."""
    game = "SeaquestNoFrameskip-v4"
    tiny = {"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}, "n_envs": 4}
    runs = {flag: train_run(game, "mc_dropout", 0, tmp_path / f"processes_{flag}", total_timesteps=128,
                            agent_kwargs={**tiny, "env_processes": flag}) for flag in (False, True)}
    configs = {flag: json.loads((out / "config.json").read_text()) for flag, out in runs.items()}
    assert configs[True]["env_processes"] and not configs[False]["env_processes"]
    assert configs[True]["gpu"] is None, "a CPU run names no accelerator"
    weights = {flag: PPO.load(resume_dir_for(out) / "model.zip", device="cpu").policy.state_dict()
               for flag, out in runs.items()}
    for name, value in weights[False].items():
        assert th.equal(value, weights[True][name]), name
    curves = {flag: (out / "training_curve.csv").read_text().splitlines() for flag, out in runs.items()}
    assert [r.split(",")[:3] for r in curves[False]] == [r.split(",")[:3] for r in curves[True]]
    model = make_agent("ppo", "mc_dropout", game, 0, env_processes=True, **tiny)
    layers, venv = [], model.get_env()
    while venv is not None:
        layers.append(type(venv).__name__)
        venv = getattr(venv, "venv", None)
    model.get_env().close()
    assert layers[-1] == "SubprocVecEnv", layers


def test_one_writer_per_run_folder_and_no_run_replaces_another(tmp_path):
    """Issue 71: two trainings into one folder, or another run's training into a finished run's folder whose resume
    point is gone (every committed checkpoint in a clone), stop before any work, naming what is there."""
    import json

    from paper_lib.agents.training import run_lock
    from paper_lib.common.io import DestinationError

    out = tmp_path / "cc"
    with run_lock(out):
        with pytest.raises(DestinationError, match=r"another process is training into .*cc"):
            train_run("CartPole-v1", "masksembles", 1, out, total_timesteps=64)
    assert not (tmp_path / ".cc.lock").exists() and not out.exists()
    out.mkdir()
    finished = {"algo": "ppo", "env_id": "CartPole-v1", "method": "masksembles", "seed": 0, "total_timesteps": 64}
    (out / "config.json").write_text(json.dumps(finished))
    (out / "model.zip").write_text("the finished run's weights")
    with pytest.raises(DestinationError, match=r"holds the finished run ppo CartPole-v1 masksembles seed 0; "
                                               r"training ppo CartPole-v1 mc_dropout seed 1 there would replace it"):
        train_run("CartPole-v1", "mc_dropout", 1, out, total_timesteps=64)
    assert (out / "model.zip").read_text() == "the finished run's weights"


def test_run_lock_name_goes_before_the_lock_so_a_late_opener_never_holds_an_orphan(tmp_path, monkeypatch):
    """Issue 71: a process that opened the lock file while the holder worked takes the kernel lock the moment it is
    released. If the name were still there it would hold a lock on a file about to be unlinked while a third process
    locks a new file of the same name: two writers. The holder unlinks first, so the late opener sees st_nlink 0
    (filelock then retries on the name) and the name is free for exactly one next holder."""
    import fcntl

    import filelock

    from paper_lib.agents.training import run_lock

    out = tmp_path / "run"
    seen: list[int] = []
    release = filelock.FileLock.release

    def release_then_late_opener_locks(self, *args, **kwargs):
        result = release(self, *args, **kwargs)
        fd = late.pop("fd", None)
        if fd is not None:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # the holder's lock is gone: this succeeds
            seen.append(os.fstat(fd).st_nlink)
            os.close(fd)
        return result

    late: dict[str, int] = {}
    monkeypatch.setattr(filelock.FileLock, "release", release_then_late_opener_locks)
    with run_lock(out) as path:
        late["fd"] = os.open(path, os.O_RDWR)
    assert seen == [0], "the late opener locked a file that still had its name: a third writer could lock a new one"
    with run_lock(out):  # exactly one next holder gets the name
        pass
