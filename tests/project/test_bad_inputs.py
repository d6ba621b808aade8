"""The catalogue of bad inputs: each is ONE clear error naming the problem, and nothing on disk changes.

Python API, params.yaml and the three CLIs (`paper_lib.agents.training`, `paper_lib.pipeline.config`,
`paper_lib.pipeline.stages`). Every case hashes the whole workspace before and after: a bad input must
neither write nor delete anything. The CLI cases run in one subprocess (imports cost seconds),
plus two plain `python -m` runs that show the real command line behaves the same.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import pickle
import re
import shutil
import subprocess
import sys
import tarfile
from collections.abc import Callable
from functools import cache, partial
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from paper_lib import make_agent, uncertainty
from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.agents.training import train_run
from paper_lib.ood.atari import AtariOODConfig
from paper_lib.ood.atari_head import LABEL_HEADER, load_atari_head_states
from paper_lib.ood.datasets import StateDataset
from paper_lib.ood.mujoco import PerturbationConfig
from paper_lib.pipeline.config import load_run_config, use_profile
from paper_lib.pipeline.evaluate_agent import Budget, evaluate_agent
from paper_lib.pipeline.run_results import load_run_dataset, read_all_replicates, read_evaluations, read_scores

REPO = Path(__file__).resolve().parents[2]
TINY = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}
_counter = itertools.count()


def snapshot(root: Path) -> dict[str, str]:
    """Every path under root -> sha256 of its bytes ('dir' for folders)."""
    out = {}
    for path in sorted(root.rglob("*")):
        key = str(path.relative_to(root))
        out[key] = "dir" if path.is_dir() else hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def _save_checkpoint(folder: Path, algo: str, method: str, config_edit: dict | None = None, env_id: str = "CartPole-v1",
                     **kwargs) -> None:
    """A checkpoint folder as train_run exports it (model.zip + config.json), built without training."""
    folder.mkdir(parents=True)
    model = make_agent(algo, method, env_id, 0, overrides=TINY if algo == "ppo" else {"n_steps": 8}, **kwargs)
    model.save(folder / "model.zip")
    (folder / "config.json").write_text(json.dumps({**model.paper_lib_config, **(config_edit or {})}))
    (folder / "training_curve.csv").write_text("timesteps,reward\n")


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> SimpleNamespace:
    """The workspace: a params.yaml copy, checkpoints with wrong identities, an Atari-HEAD copy."""
    from stable_baselines3.common.vec_env import VecNormalize

    from paper_lib.agents.envs import make_env, save_normalizer

    root = tmp_path_factory.mktemp("bad_inputs")
    shutil.copy(REPO / "params.yaml", root / "params.yaml")
    ck = root / "checkpoints"
    _save_checkpoint(ck / "masksembles", "ppo", "masksembles")
    # a Masksembles model.zip in the MC Dropout folder
    _save_checkpoint(ck / "mc_dropout", "ppo", "mc_dropout")
    shutil.copy(ck / "masksembles" / "model.zip", ck / "mc_dropout" / "model.zip")
    # an A2C model where config.json says ppo
    _save_checkpoint(ck / "a2c_as_ppo", "a2c", "ensemble", {"algo": "ppo"})
    # k=2 members where config.json says 4; other widths than config.json says
    _save_checkpoint(ck / "wrong_k", "ppo", "ensemble", {"n_members": 4}, n_members=2)
    _save_checkpoint(ck / "wrong_widths", "ppo", "baseline", {"hidden_sizes": [32, 32]})
    # a model of another env (Acrobot, with CartPole's settings) where config.json says CartPole
    _save_checkpoint(ck / "other_env", "ppo", "ensemble", {"env_id": "CartPole-v1"}, env_id="Acrobot-v1",
                     hyperparameters=yaml.safe_load((REPO / "params.yaml").read_text())["hyperparameters"]["CartPole-v1"])
    # a stray normalizer where the run did not normalize; a garbage one where it did
    _save_checkpoint(ck / "stray_norm", "ppo", "ensemble")
    VecNormalize(make_env("CartPole-v1", 1, 0)).save(str(ck / "stray_norm" / "vecnormalize.pkl"))
    _save_checkpoint(ck / "garbage_norm", "ppo", "ensemble", {"normalize_obs": True})
    (ck / "garbage_norm" / "vecnormalize.pkl").write_bytes(b"\x80\x04garbage")
    # a normalizer that records another env (of CartPole's shape) where config.json says CartPole-v1
    _save_checkpoint(ck / "norm_other_env", "ppo", "ensemble", {"normalize_obs": True})
    save_normalizer(VecNormalize(make_env("CartPole-v1", 1, 0)), ck / "norm_other_env" / "vecnormalize.pkl", "CartPole-v0")
    _save_checkpoint(ck / "bad_json", "ppo", "ensemble")
    (ck / "bad_json" / "config.json").write_text('{"env_id": "CartPole-v1",')
    # Atari-HEAD copies: a label file with a corrupt archive, and with a truncated one
    for name, damage in (("garbage", lambda p: p.write_bytes(b"BZh9 not really bzip2")),
                         ("truncated", lambda p: p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2]))):
        folder = root / "head" / name / "seaquest"
        folder.mkdir(parents=True)
        trial = "100_RZ_3592991_Aug-24-11-44-38"
        rows = [",".join(LABEL_HEADER)] + [f"RZ_3592991_{i},0,0,50,0,0,null" for i in range(1, 9)]
        (folder / f"{trial}.txt").write_text("\n".join(rows) + "\n")
        png = folder / trial
        png.mkdir()
        frame = np.random.default_rng(0).integers(0, 256, (210, 160, 3), dtype=np.uint8)
        for i in range(1, 9):
            (png / f"RZ_3592991_{i}.png").write_bytes(cv2.imencode(".png", frame)[1].tobytes())
        with tarfile.open(folder / f"{trial}.tar.bz2", "w:bz2") as tar:
            tar.add(png, arcname=trial)
        shutil.rmtree(png)
        damage(folder / f"{trial}.tar.bz2")
    # bring your own agent: a HalfCheetah zip, and a normalizer saved for Swimmer (8 observations, not 17)
    agents = root / "agents"
    agents.mkdir()
    make_agent("ppo", "baseline", "HalfCheetah-v5", 0, overrides=TINY).save(agents / "halfcheetah.zip")
    VecNormalize(make_env("Swimmer-v5", 1, 0)).save(str(agents / "swimmer_vecnormalize.pkl"))
    (agents / "not_vecnormalize.pkl").write_bytes(pickle.dumps({"obs_rms": None}))
    save_normalizer(VecNormalize(make_env("Walker2d-v5", 1, 0)), agents / "walker_saved_vecnormalize.pkl", "Walker2d-v5")
    # evaluation files cut off: mid-row, after the header, at a row boundary, to nothing (seeds 0-3 of one run)
    whole = _evaluation_text()
    lines = whole.splitlines(keepends=True)
    damaged = ("reward,length\n100.0,1000\n",  # another file's columns
               "".join(lines[:-1]) + "single,False,,,1000,HalfCheetah-v5,baseline,0\n",  # an episode without its reward
               "".join(lines) + "single,False,,1.0,1000,HalfCheetah-v5,baseline,0,7,8\n")  # a row of too many fields
    twice = whole + "".join(lines[1:])  # every episode twice (a file appended to itself)
    for seed, text in enumerate((whole[:-9], lines[0], "".join(lines[:-1]), "", *damaged, twice)):
        path = root / "evals" / "results" / "paper" / "evaluations" / "HalfCheetah-v5" / "baseline" / f"seed{seed}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    _damaged_scores(root / "scores")
    # perturbed states relabelled as ID: label and source changed, config_index still names their configuration
    StateDataset(states=np.zeros((4, 4), dtype=np.float32), labels=[0] * 4, source=["id"] * 4,
                 config_index=[-1, -1, 0, 0], episode=[0, 0, 1, 1], step=[0, 1, 0, 1],
                 configs=['{"env_id": "HalfCheetah-v5", "gravity": [0.0, 0.0, -15.0]}']).save(root / "relabelled.npz")
    cut = root / "cut" / "seed0.npz"  # a dataset cut off mid-file (a killed copy, a full disk)
    cut.parent.mkdir()
    whole = (root / "relabelled.npz").read_bytes()
    cut.write_bytes(whole[: len(whole) // 2])
    return SimpleNamespace(root=root, ck=ck, params=root / "params.yaml", text=(root / "params.yaml").read_text())


#: A committed run whose scores the score-file cases copy and damage, and another run of its env and seed.
SCORED, OTHER_SCORED = ("HalfCheetah-v5", "baseline", 0), ("HalfCheetah-v5", "masksembles", 0)


def _scores_folder(tree: Path, run: tuple[str, str, int]) -> Path:
    return tree / "results" / "paper" / "scores" / run[0] / run[1] / f"seed{run[2]}"


def _damaged_scores(root: Path) -> None:
    """One results tree per damage, each holding the committed scores of SCORED (their inputs absent, as in a checkout
    without datasets: the provenance record is checked for its identity only) with one file damaged."""
    def cut(name: str, at: Callable[[bytes], int]) -> Callable[[Path], None]:
        return lambda folder: (folder / name).write_bytes((folder / name).read_bytes()[: at((folder / name).read_bytes())])

    damages = {
        "metrics_half": cut("metrics.csv", lambda b: len(b) // 2),
        "metrics_at_a_row": cut("metrics.csv", lambda b: b.rindex(b"\n", 0, len(b) // 2) + 1),
        "replicates_half": cut("replicates.npy", lambda b: len(b) // 2),
        "roc_of_another_run": lambda folder: shutil.copy(_scores_folder(REPO, OTHER_SCORED) / "roc.csv", folder),
        "no_provenance": lambda folder: (folder / "provenance.json").unlink(),
    }
    for name, damage in damages.items():
        folder = _scores_folder(root / name, SCORED)
        shutil.copytree(_scores_folder(REPO, SCORED), folder)
        damage(folder)


def _evaluation_text() -> str:
    """A whole evaluation file of HalfCheetah baseline seed 0 as `evaluate_run` writes it: 3 episodes per action mode."""
    import pandas as pd

    rows = [{"inference": "single", "deterministic": d, "member": None, "reward": 100.0 + i, "length": 1000,
             "env": "HalfCheetah-v5", "method": "baseline", "seed": 0} for d in (True, False) for i in range(3)]
    return pd.DataFrame(rows).to_csv(index=False, lineterminator="\n")


# ------------------------------------------------------------------------------- helpers


def edited_text(ws: SimpleNamespace, old: str, new: str) -> Path:
    """A params.yaml copy with one exact text edit (what a person typing in the file does)."""
    assert ws.text.count(old) >= 1, old
    path = ws.root / f"params_{next(_counter)}.yaml"
    path.write_text(ws.text.replace(old, new, 1))
    return path


def edited(ws: SimpleNamespace, edit: Callable[[dict], Any]) -> Path:
    """A params.yaml copy with one structural edit."""
    data = yaml.safe_load(ws.text)
    edit(data)
    path = ws.root / f"params_{next(_counter)}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _set(section: str, key: str, value: Any, env: str | None = None) -> Callable[[dict], None]:
    def edit(data: dict) -> None:
        target = data[section] if env is None else data["hyperparameters"][env]
        for part in key.split(".")[:-1]:
            target = target[part]
        target[key.split(".")[-1]] = value
    return edit


def params_case(edit: Callable[[dict], Any]) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    return lambda ws: partial(load_run_config, edited(ws, edit))


def text_case(old: str, new: str) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    return lambda ws: partial(load_run_config, edited_text(ws, old, new))


def agent(**kwargs: Any) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    args = {"algo": "ppo", "method": "ensemble", "env_id": "CartPole-v1", "seed": 0, "overrides": dict(TINY), **kwargs}
    return lambda ws: partial(make_agent, **args)


def checkpoint(name: str, method: str = "ensemble") -> Callable[[SimpleNamespace], Callable[[], Any]]:
    return lambda ws: partial(load_checkpoint, ws.ck / name, "CartPole-v1", method, 0)


def perturbation(**kwargs: Any) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    return lambda ws: partial(PerturbationConfig, **{"env_id": "HalfCheetah-v5", **kwargs})


def budget(steps: Any) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    return lambda ws: partial(train_run, "CartPole-v1", "ensemble", 0, ws.root / "never_written",
                              total_timesteps=steps, agent_kwargs={"overrides": dict(TINY)})


def profile_switch(edit: Callable[[dict], Any], name: str) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    return lambda ws: partial(use_profile, name, edited(ws, edit))


def evaluation(seed: int) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    """read_evaluations (what the rewards notebook calls) on the evaluation file of seed `seed`, cut off."""
    import dataclasses

    return lambda ws: partial(read_evaluations, dataclasses.replace(load_run_config(ws.params), root=ws.root / "evals",
                                                                    eval_episodes=3), [("HalfCheetah-v5", "baseline", seed)])


def scores(damage: str, name: str = "metrics", reader: Callable | None = None) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    """read_scores (notebooks 3-5) of SCORED's `name` file in the tree with `damage`; `reader(cfg, runs)` instead."""
    import dataclasses

    def prepare(ws: SimpleNamespace) -> Callable[[], Any]:
        cfg = dataclasses.replace(load_run_config(ws.params), root=ws.root / "scores" / damage)
        return partial(reader, cfg, [SCORED]) if reader else partial(read_scores, cfg, [SCORED], name)
    return prepare


def own_agent(vecnormalize: Callable[[SimpleNamespace], Any]) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    """evaluate_agent on the HalfCheetah zip with `vecnormalize(ws)`; the budget is small, the error comes first."""
    budget = Budget(configs=2, steps_per_config=10, id_episodes=4, skip_first=2, max_episode_steps=20, n_bootstrap=20,
                    n_scoring_seeds=1)
    return lambda ws: partial(evaluate_agent, ws.root / "agents" / "halfcheetah.zip", "HalfCheetah-v5",
                              vecnormalize=vecnormalize(ws), budget=budget)


def walker_vecnormalize(ws: SimpleNamespace) -> Any:
    from stable_baselines3.common.vec_env import VecNormalize

    from paper_lib.agents.envs import make_env

    return VecNormalize(make_env("Walker2d-v5", 1, 0))  # 17 observations, as HalfCheetah's: only the env id differs


def guard(edit: Callable[[dict], Any]) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    """load_settings (notebook 8's first cell) on a params.yaml copy whose guard section has one edit."""
    from paper_lib.guard.settings import load_settings

    return lambda ws: partial(load_settings, edited(ws, lambda data: edit(data["guard"])))


def budget_entry(profile: str, key: str, value: Any) -> Callable[[dict], None]:
    def edit(section: dict) -> None:
        if key:
            section["budgets"][profile][key] = value
        else:
            section["budgets"][profile] = value
    return edit


def head(name: str) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    return lambda ws: partial(load_atari_head_states, ws.root / "head" / name, "Seaquest", 1,
                              np.random.default_rng(0), frame_skip=1)


@cache
def _cartpole(method: str = "ensemble", seed: int = 0) -> Any:
    """A CartPole agent, built once per module (the cases only read it)."""
    return make_agent("ppo", method, "CartPole-v1", seed, n_envs=4, overrides=dict(TINY))


@cache
def _seaquest() -> Any:
    """A Seaquest agent: its policy takes uint8 frames in [0, 255]."""
    return make_agent("ppo", "baseline", "SeaquestNoFrameskip-v4", 0, n_envs=2, overrides=dict(TINY))


def given_env(env_id: str) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    """make_agent for CartPole-v1 handed an env of `env_id`."""
    from paper_lib.agents.envs import make_env

    return lambda ws: partial(make_agent, "ppo", "ensemble", "CartPole-v1", 0, n_envs=4, overrides=dict(TINY),
                              env=make_env(env_id, 4, 0))


def calibrated_on(scores: np.ndarray) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    """Guard.from_scores on these calibration scores."""
    from paper_lib.guard import Guard
    from paper_lib.guard.scores import CallableScore

    return lambda ws: partial(Guard.from_scores, _cartpole(), CallableScore(lambda s: s[:, 0], "x"), scores, 0.1)


def guard_of_another_seed(ws: SimpleNamespace) -> Callable[[], Any]:
    """GuardedPolicy of the seed-1 agent with a guard calibrated on the seed-0 agent."""
    from paper_lib.guard import Guard, GuardedPolicy
    from paper_lib.guard.scores import CallableScore

    guard = Guard.from_scores(_cartpole(), CallableScore(lambda s: s[:, 0], "x"), np.arange(20.0), 0.1)
    return partial(GuardedPolicy, _cartpole(seed=1), guard, fallback=None)


def scored(obs: Callable[[], np.ndarray], atari: bool = False, **kwargs: Any) -> Callable[[SimpleNamespace], Callable[[], Any]]:
    """uncertainty on `obs()` by the Seaquest (atari) or the CartPole agent's policy."""
    return lambda ws: partial(uncertainty, (_seaquest() if atari else _cartpole()).policy, obs(), **kwargs)


def frames() -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (2, 84, 84, 4), dtype=np.uint8)


def cartpole_states() -> np.ndarray:
    return np.zeros((3, 4), dtype=np.float32)


# (id, prepare(ws) -> call, regex the one error message must match)
API_CASES: list[tuple[str, Callable, str]] = [
    # params.yaml
    ("yaml-syntax", text_case("  seeds: [0]\n", "  seeds: [0\n"), r"params_\d+\.yaml line \d+, column \d+: YAML syntax"),
    ("lr-3e-4-is-text", text_case("learning_rate: 0.0003,", "learning_rate: 3e-4,"), r"'3e-4' is text.*write 3\.0e-4"),
    ("hp-key-typo", text_case("n_steps: 512,", "n_step: 512,"), r"unknown algo setting\(s\) \['n_step'\]; known:"),
    ("hp-key-missing", params_case(lambda d: d["hyperparameters"]["Ant-v5"]["algo"].pop("n_steps")),
     r"Ant-v5: algo lacks \['n_steps'\]"),
    ("budget-negative", params_case(_set("run", "total_timesteps", -5)), r"total_timesteps must be an integer >= 1"),
    ("budget-fraction", params_case(_set("run", "total_timesteps", 2.5)), r"total_timesteps must be an integer, got 2\.5"),
    ("budget-zero", params_case(_set("profiles", "tiny.total_timesteps", 0)), r"profiles\.tiny.*total_timesteps.*>= 1"),
    ("hp-budget-negative", params_case(_set("hyperparameters", "total_timesteps", -1, env="Swimmer-v5")),
     r"Swimmer-v5: total_timesteps must be an integer >= 1"),
    ("run-key-typo", params_case(_set("run", "n_id_state", 5)), r"unknown setting\(s\) \['n_id_state'\]; known:"),
    ("top-level-typo", params_case(lambda d: d.update(hyperparameter={})), r"unknown top-level section"),
    ("seed-string", params_case(_set("run", "seeds", ["0"])), r"seed must be an integer, got '0'"),
    ("seed-negative", params_case(_set("run", "seeds", [-1])), r"seed must be an integer >= 0"),
    ("seeds-empty", params_case(_set("run", "seeds", [])), r"seeds must be a non-empty list"),
    ("width-zero", params_case(_set("hyperparameters", "hidden_sizes", [0, 64], env="Ant-v5")),
     r"Ant-v5: hidden_sizes\[0\] must be an integer >= 1"),
    ("n-envs-zero", params_case(_set("hyperparameters", "n_envs", 0, env="Ant-v5")), r"Ant-v5: n_envs must be an integer >= 1"),
    ("override-batch-zero", params_case(_set("run", "overrides", {"batch_size": 0})),
     r"overrides\.batch_size must be an integer >= 2"),
    ("override-typo", params_case(_set("run", "overrides", {"n_epoch": 2})), r"unknown overrides setting\(s\) \['n_epoch'\]"),
    ("override-layout", params_case(_set("run", "overrides", {"batch_size": 30})), r"batch_size=30 is not a multiple"),
    ("gamma-above-1", params_case(_set("hyperparameters", "algo.gamma", 1.5, env="Swimmer-v5")), r"algo\.gamma=1\.5 is outside \[0, 1\]"),
    ("dropout-p-1", params_case(_set("hyperparameters", "members.dropout_p", 1.0, env="Swimmer-v5")),
     r"members\.dropout_p=1\.0 is outside \[0, 1\)"),
    ("deterministic-not-bool", params_case(_set("run", "deterministic", 1)), r"deterministic must be true or false"),
    ("inference-unknown", params_case(_set("run", "inference", "majority")), r"unknown inference mode 'majority'"),
    ("method-twice", params_case(_set("run", "methods", ["baseline", "baseline"])), r"methods lists an entry twice"),
    ("skip-all", params_case(_set("run", "skip_first", 500)), r"skip_first=500 drops every state"),
    ("normalize-not-bool", params_case(_set("hyperparameters", "normalize_obs", "no", env="Ant-v5")),
     r"normalize_obs must be true or false"),
    ("use-broken-profile", profile_switch(_set("profiles", "paper.total_timesteps", -5), "paper"),
     r"profiles\.paper.*total_timesteps.*left unchanged"),
    ("use-unknown-profile", lambda ws: partial(use_profile, "huge", ws.params), r"params\.yaml: unknown profile 'huge'"),
    # make_agent
    ("n-envs-0", agent(n_envs=0), r"n_envs must be an integer >= 1, got 0"),
    ("n-envs-negative", agent(n_envs=-4), r"n_envs must be an integer >= 1, got -4"),
    ("n-envs-below-k", agent(n_envs=2), r"n_envs=2 is fewer than n_members=4"),
    ("n-envs-not-multiple", agent(n_envs=6), r"n_envs=6 is not a multiple of n_members=4"),
    ("n-envs-float", agent(n_envs=8.0), r"n_envs must be an integer, got 8\.0 \(write 8\)"),
    ("seed-str", agent(seed="0"), r"seed must be an integer, got '0'"),
    ("seed-neg", agent(seed=-1), r"seed must be an integer >= 0"),
    ("seed-float", agent(seed=1.5), r"seed must be an integer, got 1\.5"),
    ("batch-size-0", agent(overrides={"batch_size": 0}), r"overrides\.batch_size must be an integer >= 2"),
    ("lr-string", agent(overrides={"learning_rate": "3e-4"}), r"write 3\.0e-4"),
    ("override-unknown", agent(overrides={"n_stepz": 3}), r"unknown override"),
    ("overrides-not-dict", agent(overrides=[("n_steps", 16)]), r"overrides must be a dict"),
    ("k-float", agent(n_members=2.5), r"n_members must be an integer"),
    ("p-string", agent(method="mc_dropout", dropout_p="0.1"), r"dropout_p='0\.1' is text"),
    ("width-0-api", lambda ws: partial(make_agent, "ppo", "baseline", "CartPole-v1", 0,
                                        hyperparameters={**yaml.safe_load(ws.text)["hyperparameters"]["CartPole-v1"],
                                                         "hidden_sizes": [64, 0]}), r"hidden_sizes\[1\] must be an integer >= 1"),
    ("env-not-str", agent(env_id=5), r"env_id must be a Gymnasium id string"),
    # budgets given to train_run
    ("train-budget-negative", budget(-5), r"total_timesteps must be a positive integer, got -5"),
    ("train-budget-fraction", budget(2.5), r"total_timesteps must be a positive integer, got 2\.5"),
    ("train-budget-zero", budget(0), r"total_timesteps must be a positive integer, got 0"),
    # checkpoints: identity from the artifact itself
    ("masksembles-zip-in-mc-dropout", checkpoint("mc_dropout", "mc_dropout"),
     r"mc_dropout/model\.zip does not belong to .*method 'masksembles' \(config\.json: 'mc_dropout'\)"),
    ("a2c-zip-as-ppo", checkpoint("a2c_as_ppo"), r"a2c_as_ppo/model\.zip .*algorithm 'a2c' \(config\.json: 'ppo'\)"),
    ("k-mismatch", checkpoint("wrong_k"), r"wrong_k/model\.zip .*k=2 members \(config\.json: n_members=4\)"),
    ("width-mismatch", checkpoint("wrong_widths", "baseline"), r"hidden widths \[64, 64\] \(config\.json: \[32, 32\]\)"),
    ("other-env-zip", checkpoint("other_env"), r"other_env/model\.zip takes observations .*\(6,\).* but CartPole-v1 has"),
    ("stray-vecnormalize", checkpoint("stray_norm"), r"stray_norm/vecnormalize\.pkl is present but .*normalize_obs: false"),
    ("garbage-vecnormalize", checkpoint("garbage_norm"), r"garbage_norm/vecnormalize\.pkl is not a readable"),
    ("config-json-broken", checkpoint("bad_json"), r"bad_json/config\.json is not valid JSON"),
    ("checkpoint-other-method", checkpoint("masksembles", "ensemble"),
     r"trained with method='masksembles' but this stage expects 'ensemble'"),
    # perturbation configurations
    ("friction-1e6", perturbation(friction_scale=1e6), r"friction_scale=1e\+06 .*paper's ranges.*outside_ranges=True"),
    ("gravity-upward", perturbation(gravity=(0.0, 0.0, 50.0)), r"gravity=\(0\.0, 0\.0, 50\.0\).*paper's ranges"),
    ("geometry-x50", perturbation(geometry_scales={"bthigh": 50.0}), r"geometry_scales\['bthigh'\]=50.*paper's ranges"),
    ("wind-5", perturbation(wind=(5.0, 0.0, 0.0), density=1.2), r"wind=.*speed in \[0\.0, 1\.0\]"),
    ("friction-string", perturbation(friction_scale="2"), r"friction_scale='2': must be a finite number"),
    ("geometry-list", perturbation(geometry_scales=[2.0]), r"geometry_scales=\[2\.0\]: give a mapping"),
    ("perturbation-seed-str", perturbation(seed="3"), r"seed='3': must be an integer"),
    ("gravity-scalar-json", lambda ws: partial(PerturbationConfig.from_json, '{"env_id": "HalfCheetah-v5", "gravity": 2.0}'),
     r"gravity must be a list of 3 numbers"),
    ("invalid-json", lambda ws: partial(PerturbationConfig.from_json, '{"env_id": "HalfCheetah-v5", "gravity": [0,'),
     r"PerturbationConfig JSON is not valid JSON"),
    ("atari-config-invalid-json", lambda ws: partial(AtariOODConfig.from_json, "{game: Seaquest}"), r"AtariOODConfig JSON is not valid"),
    # Atari-HEAD
    ("atari-head-garbage-archive", head("garbage"), r"archive .*garbage/seaquest/100_RZ_3592991_Aug-24-11-44-38\.tar\.bz2 is corrupt"),
    ("atari-head-truncated-archive", head("truncated"), r"archive .*truncated/seaquest/.*\.tar\.bz2 is corrupt"),
    # bring your own agent: a normalizer of another env, refused before any collection
    ("vecnormalize-other-shape", own_agent(lambda ws: ws.root / "agents" / "swimmer_vecnormalize.pkl"),
     r"agents/swimmer_vecnormalize\.pkl normalizes observations of shape \(8,\), but HalfCheetah-v5's have shape "
     r"\(17,\): it belongs to another env; give the VecNormalize the agent was trained with on HalfCheetah-v5"),
    ("vecnormalize-not-one", own_agent(lambda ws: ws.root / "agents" / "not_vecnormalize.pkl"),
     r"cannot load .*not_vecnormalize\.pkl as a VecNormalize for HalfCheetah-v5 \(TypeError: it holds a dict\)"),
    ("vecnormalize-other-env", own_agent(walker_vecnormalize),
     r"the VecNormalize wraps Walker2d-v5, but the agent is evaluated on HalfCheetah-v5"),
    # evaluation files cut off: the file named, not an error deep in the statistics
    ("evaluation-cut-mid-row", evaluation(0), r"evaluations/HalfCheetah-v5/baseline/seed0\.csv is incomplete \(cut off\?\): "
     r"its last line ends mid-row; evaluate the run again \(`python -m paper_lib\.pipeline\.run_results evaluate "
     r"HalfCheetah-v5 baseline 0`\)"),
    ("evaluation-header-only", evaluation(1), r"seed1\.csv is incomplete .*: it holds a header but no episode"),
    ("evaluation-cut-at-a-row", evaluation(2), r"seed2\.csv is incomplete .*: each action mode and inference needs as "
     r"many episodes as the others, got 3 single deterministic, 2 single sampled"),
    ("evaluation-empty", evaluation(3), r"seed3\.csv is incomplete .*: it is empty"),
    ("evaluation-other-columns", evaluation(4), r"seed4\.csv is incomplete .*: it lacks the column\(s\) \['inference', "),
    ("evaluation-empty-reward", evaluation(5), r"seed5\.csv is incomplete .*: some episodes have no reward;"),
    ("evaluation-unparsable", evaluation(6), r"seed6\.csv is incomplete .*: it is not a readable CSV \(ParserError: "),
    ("evaluation-every-episode-twice", evaluation(7), r"seed7\.csv holds 6 episodes per action mode and inference, but "
     r"the profile plays 3 \(eval_episodes\): episodes were added twice or the file is of another profile; evaluate the "
     r"run again \(`python -m paper_lib\.pipeline\.run_results evaluate HalfCheetah-v5 baseline 7`\)"),
    ("dataset-relabelled-ood-states", lambda ws: partial(StateDataset.load, ws.root / "relabelled.npz"),
     r"relabelled\.npz: 2 of 4 states of source 'id' point at an OOD configuration \(e\.g\. state 2: config_index 0\); "
     r"ID states are collected in the unmodified env \(config_index -1\), so these are relabelled OOD states: collect "
     r"the states again \(`make recollect`\) or correct the labels"),
    ("dataset-cut-in-half", lambda ws: partial(load_run_dataset, ws.root / "cut" / "seed0.npz", "HalfCheetah-v5",
                                               "baseline", 0),
     r"cut/seed0\.npz is not a readable StateDataset \(BadZipFile: .*\); the file is damaged or was written by something "
     r"else: restore the committed copy \(`git checkout -- .*cut/seed0\.npz`\) or collect it again \(`dvc repro -s "
     r"collect@HalfCheetah-v5-baseline-0`; `make recollect` collects every run's\)"),
    # score files cut off, of another run, or without their record (issue 71)
    ("scores-metrics-cut-in-half", scores("metrics_half"), r"metrics_half/results/paper/scores/HalfCheetah-v5/baseline/"
     r"seed0/metrics\.csv is incomplete \(cut off\?\): its last line ends mid-row; score the run again \(`python -m "
     r"paper_lib\.pipeline\.run_results score HalfCheetah-v5 baseline 0`\)"),
    ("scores-metrics-cut-at-a-row", scores("metrics_at_a_row"), r"seed0/replicates\.npy holds \d+ rows but the "
     r"metrics\.csv beside it has \d+ \(one row of replicates per metric\): one of them is cut off .*; score the run again"),
    ("scores-replicates-cut", scores("replicates_half", reader=read_all_replicates), r"seed0/replicates\.npy is "
     r"incomplete \(cut off\?\): it is not a readable \.npy .*; score the run again \(`python -m "
     r"paper_lib\.pipeline\.run_results score HalfCheetah-v5 baseline 0`\)"),
    ("scores-file-of-another-run", scores("roc_of_another_run", "roc"), r"seed0/roc\.csv belongs to HalfCheetah-v5 "
     r"masksembles seed 0, not to HalfCheetah-v5 baseline seed 0 whose path it sits at: a file of another run is never "
     r"read as this one's; score the run again"),
    ("scores-without-provenance", scores("no_provenance", "over_time"), r"the scores .*no_provenance/results/paper/"
     r"scores/HalfCheetah-v5/baseline/seed0 have no provenance\.json: .*record it from the current files, which the "
     r"command checks first \(`python -m paper_lib\.pipeline\.run_results provenance HalfCheetah-v5 baseline 0`\)"),
    # notebook 8's guard budgets (the active profile's and every other's)
    ("guard-budget-negative", guard(budget_entry("paper", "fit_episodes", -3)),
     r"params_\d+\.yaml: guard\.budgets\.paper\.fit_episodes must be an integer >= 1, got -3"),
    ("guard-budget-fraction", guard(budget_entry("paper", "episode_steps", 200.5)),
     r"params_\d+\.yaml: guard\.budgets\.paper\.episode_steps must be an integer >= 2, got 200\.5"),
    ("guard-budget-zero", guard(budget_entry("paper", "perturbed_episodes", 0)),
     r"guard\.budgets\.paper\.perturbed_episodes must be an integer >= 1, got 0"),
    ("guard-budget-text", guard(budget_entry("paper", "id_test_episodes", "40")),
     r"guard\.budgets\.paper\.id_test_episodes must be an integer >= 1, got '40'"),
    ("guard-budget-key-typo", guard(budget_entry("paper", "calibraton_episodes", 100)),
     r"params_\d+\.yaml: guard\.budgets\.paper: unknown key\(s\) \['calibraton_episodes'\]"),
    ("guard-other-profile-negative", guard(budget_entry("tiny", "fit_episodes", -1)),
     r"guard\.budgets\.tiny\.fit_episodes must be an integer >= 1, got -1"),
    ("guard-budget-not-mapping", guard(budget_entry("paper", "", [10, 100])),
     r"guard\.budgets\.paper must be a mapping \{fit_episodes: \.\.\., .*\}, got \[10, 100\]"),
    # issue 71: doors that were open
    ("make-agent-env-of-another-id", given_env("Acrobot-v1"),
     r"make_agent: the given env runs Acrobot-v1 but env_id is 'CartPole-v1'; pass an env of CartPole-v1 "
     r"\(make_env\('CartPole-v1', n_envs, seed\)\) or env_id='Acrobot-v1'"),
    ("guard-of-another-model", guard_of_another_seed,
     r"the guard was calibrated for a PPO ensemble CartPole-v1, seed 0 \(weights [0-9a-f]{12}\), but the model given "
     r"is a PPO ensemble CartPole-v1, seed 1 \(weights [0-9a-f]{12}\); .*Pass the model the guard was calibrated with, "
     r"or calibrate a new guard for this model"),
    ("guard-calibrated-on-inf", calibrated_on(np.r_[np.arange(19.0), np.inf]),
     r"calibration scores hold NaN or inf \(1 of 20; an inf threshold never alarms, -inf always does\); drop those "
     r"calibration states or fix the score function"),
    ("guard-calibrated-on-minus-inf", calibrated_on(np.r_[np.arange(19.0), -np.inf]), r"hold NaN or inf \(1 of 20"),
    ("checkpoint-normalizer-of-another-env", checkpoint("norm_other_env"),
     r"norm_other_env/vecnormalize\.pkl was saved for CartPole-v0 but .*norm_other_env/config\.json says CartPole-v1: "
     r"another run's normalizer was put here; retrain it"),
    ("vecnormalize-saved-for-other-env", own_agent(lambda ws: ws.root / "agents" / "walker_saved_vecnormalize.pkl"),
     r"walker_saved_vecnormalize\.pkl was saved for Walker2d-v5, but the agent is evaluated on HalfCheetah-v5: give "
     r"the VecNormalize the agent was trained with on HalfCheetah-v5"),
    ("uncertainty-seed-fraction", scored(cartpole_states, seed=1.5),
     r"seed must be None or an integer >= 0 \(the MC masks' seed\), got 1\.5; pass e\.g\. seed=0"),
    ("uncertainty-seed-text", scored(cartpole_states, seed="7"), r"seed must be None or an integer >= 0 .*got '7'"),
    ("uncertainty-frames-scaled", scored(lambda: frames().astype(np.float32) / 255, atari=True),
     r"observations are float32 but this policy's observation space holds uint8 frames in \[0, 255\]; pass the raw "
     r"frames \(the policy scales them itself\)"),
    ("uncertainty-frames-negative", scored(lambda: frames().astype(np.int64) - 128, atari=True),
     r"observations hold values in \[-128, 127\] but this policy's observation space holds uint8 frames in "
     r"\[0, 255\]; pass the raw frames as the env returns them"),
    ("uncertainty-not-a-policy", lambda ws: partial(uncertainty, "model.zip", cartpole_states()),
     r"uncertainty takes an SB3 actor-critic model or its policy \(model\.policy\), got str; pass e\.g\. "
     r"make_agent\(\.\.\.\) or PPO\.load\(path\)"),
]


@pytest.mark.parametrize("case_id,prepare,match", API_CASES, ids=[c[0] for c in API_CASES])
def test_bad_input_is_one_clear_error_and_changes_nothing(ws, case_id, prepare, match, monkeypatch):
    monkeypatch.chdir(ws.root)  # MuJoCo writes its log to the working directory
    call = prepare(ws)
    before = snapshot(ws.root)
    with pytest.raises(ValueError) as err:
        call()
    assert type(err.value) is ValueError, f"{case_id}: {type(err.value).__name__} is not a plain ValueError"
    message = str(err.value)
    assert re.search(match, message), f"{case_id}: {message!r} does not match {match!r}"
    assert "\n" not in message, f"{case_id}: one line, got {message!r}"
    assert snapshot(ws.root) == before, f"{case_id}: the bad input changed files on disk"


def test_catalogue_is_large_enough():
    assert len(API_CASES) + len(CLI_CASES) >= 40


# ----------------------------------------------------------------------------------- CLIs

#: Runs each (module, argv, cwd) as `python -m module argv` would, in one interpreter.
DRIVER = r"""
import contextlib, io, json, os, runpy, sys, traceback, warnings
warnings.simplefilter("ignore")
results = []
for module, argv, cwd in json.load(sys.stdin):
    os.chdir(cwd)
    sys.argv = [module, *argv]
    err, code = io.StringIO(), 0
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            runpy.run_module(module, run_name="__main__", alter_sys=True)
        except SystemExit as exit:
            code = exit.code if isinstance(exit.code, int) else 1
        except BaseException:
            traceback.print_exc()
            code = 1
    results.append([code, err.getvalue()])
print(json.dumps(results))
"""

TRAIN = ["CartPole-v1", "ensemble", "0", "out"]
#: (id, module, argv, which params file the cwd holds, regex of the one error line)
CLI_CASES: list[tuple[str, str, list[str], str, str]] = [
    ("timesteps-0", "paper_lib.agents.training", [*TRAIN, "--timesteps", "0"], "good", r"total_timesteps must be a positive integer, got 0"),
    ("timesteps-negative", "paper_lib.agents.training", [*TRAIN, "--timesteps", "-100"], "good", r"positive integer, got -100"),
    ("timesteps-fraction", "paper_lib.agents.training", [*TRAIN, "--timesteps", "2.5"], "good", r"invalid int value: '2\.5'"),
    ("resume-every-0", "paper_lib.agents.training", [*TRAIN, "--resume-every", "0"], "good", r"--resume-every must be a positive"),
    ("threads-0", "paper_lib.agents.training", [*TRAIN, "--threads", "0"], "good", r"--threads must be a positive"),
    ("device-unknown", "paper_lib.agents.training", [*TRAIN, "--device", "gpu0"], "good", r"--device must be a torch device such as cpu or cuda, got .gpu0."),
    ("train-seed-negative", "paper_lib.agents.training", ["CartPole-v1", "ensemble", "-1", "out"], "good", r"seed must be an integer >= 0"),
    ("train-method-unknown", "paper_lib.agents.training", ["CartPole-v1", "bayes", "0", "out"], "good", r"unknown method 'bayes'"),
    ("train-env-unknown", "paper_lib.agents.training", ["Hopper-v5", "ensemble", "0", "out"], "good", r"unknown environment 'Hopper-v5'"),
    ("train-algo-unknown", "paper_lib.agents.training", [*TRAIN, "--algo", "sac"], "good", r"unknown algorithm 'sac'"),
    ("hp-typo", "paper_lib.agents.training", [*TRAIN, "--hp", "algo.n_step=4"], "good", r"unknown setting 'n_step'"),
    ("hp-lr-text", "paper_lib.agents.training", [*TRAIN, "--hp", "algo.learning_rate=3e-4"], "good", r"write 3\.0e-4"),
    ("hp-n-envs-0", "paper_lib.agents.training", [*TRAIN, "--hp", "n_envs=0"], "good", r"n_envs must be an integer >= 1"),
    ("hp-width-0", "paper_lib.agents.training", [*TRAIN, "--hp", "hidden_sizes=[0, 64]"], "good", r"hidden_sizes\[0\] must be"),
    ("hp-k-3", "paper_lib.agents.training", [*TRAIN, "--hp", "members.n_members=3"], "good", r"n_envs=8 is not a multiple of n_members=3"),
    ("config-use-unknown", "paper_lib.pipeline.config", ["use", "huge"], "good", r"unknown profile 'huge'"),
    ("config-use-broken", "paper_lib.pipeline.config", ["use", "tiny"], "broken_tiny", r"profiles\.tiny.*left unchanged"),
    ("config-show-syntax", "paper_lib.pipeline.config", ["show"], "syntax", r"params\.yaml line \d+, column \d+: YAML syntax"),
    ("config-show-lr-text", "paper_lib.pipeline.config", ["show"], "lr_text", r"write 3\.0e-4"),
    ("pipeline-bad-params", "paper_lib.pipeline.stages", ["collect", "HalfCheetah-v5", "baseline", "0"], "budget",
     r"total_timesteps must be an integer, got 2\.5"),
    ("pipeline-no-checkpoint", "paper_lib.pipeline.stages", ["collect", "HalfCheetah-v5", "baseline", "0"], "good",
     r"checkpoint file .*model\.zip is missing"),
    ("pipeline-train-moved", "paper_lib.pipeline.stages", ["train", "HalfCheetah-v5", "baseline", "0"], "good",
     r"invalid choice: 'train' \(choose from '?collect'?\)"),  # one training command line: paper_lib.agents.training
    ("train-method", "paper_lib.agents.training", ["HalfCheetah-v5", "bayes", "0", "out"], "good", r"unknown method 'bayes'"),
    # the default budget collects for minutes: the normalizer of another env is refused at the door
    ("evaluate-agent-other-vecnormalize", "paper_lib.pipeline.evaluate_agent",
     ["agent.zip", "HalfCheetah-v5", "--vecnormalize", "swimmer.pkl"], "good",
     r"swimmer\.pkl normalizes observations of shape \(8,\), but HalfCheetah-v5's have shape \(17,\)"),
    ("evaluate-agent-saved-vecnormalize-of-another-env", "paper_lib.pipeline.evaluate_agent",
     ["agent.zip", "HalfCheetah-v5", "--vecnormalize", "walker.pkl"], "good",
     r"walker\.pkl was saved for Walker2d-v5, but the agent is evaluated on HalfCheetah-v5"),
    ("evaluate-agent-out-empty", "paper_lib.pipeline.evaluate_agent", ["agent.zip", "HalfCheetah-v5", "--out", ""],
     "good", r"--out folder is empty \(''\), which would write into the current folder; give a folder path"),
]


def _cli_workspace(root: Path) -> dict[str, Path]:
    """One folder per params.yaml variant; the CLIs read ./params.yaml."""
    text = (REPO / "params.yaml").read_text()
    variants = {
        "good": text,
        "broken_tiny": text.replace("    total_timesteps: 256\n", "    total_timesteps: -5\n", 1),
        "syntax": text.replace("hyperparameters:\n", "hyperparameters\n  : [\n", 1),
        "lr_text": text.replace("learning_rate: 0.0003,", "learning_rate: 3e-4,", 1),
        "budget": text.replace("  total_timesteps: null\n", "  total_timesteps: 2.5\n", 1),
    }
    folders = {}
    for name, variant in variants.items():
        assert name == "good" or variant != text, name
        folders[name] = root / name
        folders[name].mkdir()
        (folders[name] / "params.yaml").write_text(variant)
    from stable_baselines3.common.vec_env import VecNormalize

    from paper_lib.agents.envs import make_env, save_normalizer

    make_agent("ppo", "baseline", "HalfCheetah-v5", 0, overrides=TINY).save(folders["good"] / "agent.zip")
    VecNormalize(make_env("Swimmer-v5", 1, 0)).save(str(folders["good"] / "swimmer.pkl"))
    save_normalizer(VecNormalize(make_env("Walker2d-v5", 1, 0)), folders["good"] / "walker.pkl", "Walker2d-v5")
    return folders


def _error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("error:") or ": error:" in line]


def test_cli_bad_inputs_exit_with_one_line_and_change_nothing(tmp_path):
    folders = _cli_workspace(tmp_path)
    before = snapshot(tmp_path)
    jobs = [[module, argv, str(folders[where])] for _, module, argv, where, _ in CLI_CASES]
    done = subprocess.run([sys.executable, "-c", DRIVER], input=json.dumps(jobs), capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads(done.stdout.strip().splitlines()[-1])
    for (case_id, _, _, _, match), (code, stderr) in zip(CLI_CASES, results):
        assert code != 0, f"{case_id}: exit code 0"
        assert "Traceback" not in stderr, f"{case_id}: traceback instead of one line:\n{stderr}"
        lines = _error_lines(stderr)
        assert len(lines) == 1 and re.search(match, lines[0]), f"{case_id}: {stderr!r} should be one line matching {match!r}"
    assert snapshot(tmp_path) == before, "a bad command line changed files on disk"


def test_real_command_lines_fail_the_same_way(tmp_path):
    """Two of the cases through `python -m`, as a person types them."""
    folders = _cli_workspace(tmp_path)
    before = snapshot(tmp_path)
    for cwd, args, match in (
        (folders["broken_tiny"], ["-m", "paper_lib.pipeline.config", "use", "tiny"], r"profiles\.tiny.*left unchanged"),
        (folders["good"], ["-m", "paper_lib.agents.training", *TRAIN, "--timesteps", "-100"], r"positive integer, got -100"),
    ):
        done = subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
        lines = _error_lines(done.stderr)
        assert len(lines) == 1 and re.search(match, lines[0]), done.stderr
    assert snapshot(tmp_path) == before
