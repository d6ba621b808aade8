"""Independently trained ensembles (appendix B.2) and `own` vs `shared`: real tiny SB3 runs, the notebook at tiny."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch as th
import yaml
from conftest import TINY
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from paper_lib import make_agent, member_outputs, uncertainty
from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.agents.envs import make_env
from paper_lib.experiments import ensembles as ens
from paper_lib.measures.estimates import policy_features
from paper_lib.methods.buffer import MemberOrderedRolloutBuffer
from paper_lib.methods.groups import member_of_env
from paper_lib.methods.independent import IndependentEnsemblePolicy, assemble_ensemble, load_independent_ensemble
from paper_lib.methods.policy import combine_actions

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
APPENDIX_ENVS = ["Walker2d-v5", "Swimmer-v5", "MsPacmanNoFrameskip-v4", "SpaceInvadersNoFrameskip-v4"]


def write_params(folder: Path, profile: str = "tiny", section: dict | None = None) -> Path:
    """The repository's params.yaml with `profile` active and, if given, this `ensembles` section instead."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["run"] = {"profile": profile, **copy.deepcopy(params["profiles"][profile])}
    if section is not None:
        params["ensembles"] = section
    path = folder / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


def section(independent: dict, own_vs_shared: dict, size: int = 4, profile: str = "tiny") -> dict:
    return {"rule": {"budget_fraction": 0.25, "epochs_factor": 4, "ensemble_size": size},
            "profiles": {profile: {"independent": independent, "own_vs_shared": own_vs_shared}}}


#: A small matrix for the tests that do not read the committed one: Walker2d members (they normalize), one own run.
TINY_SECTION = section({"envs": ["Walker2d-v5"], "member_seeds": [0, 1, 2, 3, 4], "total_timesteps": None},
                       {"envs": ["HalfCheetah-v5"], "methods": ["masksembles"], "seeds": [0]})


def rollout_states(env_id: str, n: int, seed: int) -> np.ndarray:
    """Raw states of a plain env under random actions (what an assembled ensemble takes)."""
    venv = make_env(env_id, 1, seed)
    venv.action_space.seed(seed)
    obs = [venv.reset()]
    for _ in range(n - 1):
        obs.append(venv.step(np.array([venv.action_space.sample()]))[0])
    venv.close()
    return np.concatenate(obs)


@pytest.fixture(scope="module")
def cartpole_members():
    members = []
    for seed in range(5):
        model = make_agent("ppo", "baseline", "CartPole-v1", seed, overrides=TINY)
        members.append(model.learn(128))
    return members


@pytest.fixture(scope="module")
def walker(tmp_path_factory):
    """Two Walker2d members trained by the ensembles module (rule, VecNormalize) and their config."""
    root = tmp_path_factory.mktemp("walker")
    params = write_params(root, section=section({"envs": ["Walker2d-v5"], "member_seeds": [0, 1],
                                                  "total_timesteps": None},
                                                 {"envs": ["Walker2d-v5"], "methods": ["masksembles"], "seeds": [0]},
                                                 size=2))
    cfg = ens.load_ensembles_config(params)
    for seed in (0, 1):
        ens.train_member(cfg, "Walker2d-v5", seed)
    return cfg


# ------------------------------------------------------------------------------- the policy


def test_assembled_members_answer_exactly_like_each_member(cartpole_members):
    model = assemble_ensemble(cartpole_members[:4])
    assert isinstance(model.policy, IndependentEnsemblePolicy) and model.policy.n_members == 4
    obs = rollout_states("CartPole-v1", 30, seed=3)
    out = member_outputs(model.policy, obs)
    own = [member_outputs(m.policy, obs) for m in cartpole_members[:4]]
    for j, o in enumerate(own):
        np.testing.assert_array_equal(out.values[j], o.values[0])
        np.testing.assert_array_equal(out.action_params[j], o.action_params[0])
    u = uncertainty(model.policy, obs)
    np.testing.assert_allclose(u["value_std"], np.stack([o.values[0] for o in own]).std(0), rtol=1e-5, atol=1e-7)
    assert set(u) >= {"value_std", "policy_std", "policy_js", "max_prob", "entropy"}
    latents = [m.policy.mlp_extractor.forward_actor(m.policy.extract_features(m.policy.obs_to_tensor(obs)[0]))
               for m in cartpole_members[:4]]
    np.testing.assert_allclose(policy_features(model.policy, obs), th.stack(latents).mean(0).detach().numpy(),
                               rtol=1e-6)


def test_each_member_applies_its_own_normalizer_to_raw_observations(walker):
    checkpoint = ens.assemble_members(walker, "Walker2d-v5", (0, 1))
    assert checkpoint.vecnormalize_path is None and checkpoint.config["members_normalize_obs"]
    raw = rollout_states("Walker2d-v5", 25, seed=5)
    out = member_outputs(checkpoint.model.policy, raw)
    means = []
    for j, seed in enumerate((0, 1)):
        member = load_checkpoint(walker.member_dir("Walker2d-v5", seed), "Walker2d-v5", "baseline", seed)
        normalizer = VecNormalize.load(str(member.vecnormalize_path), make_env("Walker2d-v5", 1, 0))
        means.append(normalizer.obs_rms.mean)
        own = member_outputs(member.model.policy, normalizer.normalize_obs(raw))
        np.testing.assert_array_equal(out.values[j], own.values[0])
        np.testing.assert_array_equal(out.action_params[j], own.action_params[0])
        unnormalized = member_outputs(member.model.policy, raw)  # what a member would say without its statistics
        assert not np.allclose(out.values[j], unnormalized.values[0])
    assert not np.allclose(means[0], means[1])  # two members, two different sets of statistics


def test_inference_modes_combine_members_like_member_policies(cartpole_members, walker):
    model = assemble_ensemble(cartpole_members[:4])
    policy = model.policy
    obs = rollout_states("CartPole-v1", 40, seed=7)
    pi = th.as_tensor(member_outputs(policy, obs).action_params)
    for mode in ("vote", "average"):
        for deterministic in (True, False):
            policy.set_inference(mode)
            th.manual_seed(11)
            expected = combine_actions(pi, policy, mode, None, deterministic, **policy.inference_options).numpy()
            th.manual_seed(11)
            np.testing.assert_array_equal(model.predict(obs, deterministic=deterministic)[0], expected)
    policy.set_inference("average")
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0],
                                  th.softmax(pi, -1).mean(0).argmax(-1).numpy())
    for m in range(4):
        policy.set_inference("single", member=m)
        np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0],
                                      cartpole_members[m].predict(obs, deterministic=True)[0])

    checkpoint = ens.assemble_members(walker, "Walker2d-v5", (0, 1))
    policy, raw = checkpoint.model.policy, rollout_states("Walker2d-v5", 20, seed=9)
    members = [load_checkpoint(walker.member_dir("Walker2d-v5", s), "Walker2d-v5", "baseline", s) for s in (0, 1)]
    normalized = [VecNormalize.load(str(m.vecnormalize_path), make_env("Walker2d-v5", 1, 0)).normalize_obs(raw)
                  for m in members]
    means = th.as_tensor(member_outputs(policy, raw).action_params)
    policy.set_inference("vote")
    np.testing.assert_allclose(checkpoint.model.predict(raw, deterministic=True)[0],
                               np.clip(means.mean(0).numpy(), -1, 1), rtol=1e-6)
    log_stds = th.stack([m.model.policy.log_std for m in members])
    np.testing.assert_allclose(policy.log_std.detach(), log_stds.mean(0).detach(), rtol=1e-6)
    for j, member in enumerate(members):  # single: the member's own mean and its own std
        policy.set_inference("single", member=j)
        for deterministic in (True, False):
            th.manual_seed(5)
            ours = checkpoint.model.predict(raw, deterministic=deterministic)[0]
            th.manual_seed(5)
            np.testing.assert_allclose(ours, member.model.predict(normalized[j], deterministic=deterministic)[0],
                                       rtol=1e-6)


def test_save_and_plain_ppo_load_round_trip(tmp_path, cartpole_members, walker):
    walker_ensemble = ens.assemble_members(walker, "Walker2d-v5", (0, 1)).model
    for model, obs in ((assemble_ensemble(cartpole_members[1:5]), rollout_states("CartPole-v1", 10, 1)),
                       (walker_ensemble, rollout_states("Walker2d-v5", 10, 1))):
        model.policy.set_inference("single", member=1)
        model.save(tmp_path / "ensemble.zip")
        loaded = PPO.load(tmp_path / "ensemble.zip")
        assert isinstance(loaded.policy, IndependentEnsemblePolicy) and loaded.policy.inference == ("single", 1)
        assert loaded.paper_lib_config == model.paper_lib_config
        before, after = member_outputs(model.policy, obs), member_outputs(loaded.policy, obs)
        np.testing.assert_array_equal(before.values, after.values)
        np.testing.assert_array_equal(before.action_params, after.action_params)
        np.testing.assert_array_equal(load_independent_ensemble(tmp_path / "ensemble.zip").predict(
            obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    cartpole_members[0].save(tmp_path / "baseline.zip")
    with pytest.raises(ValueError, match="not an assembled independent ensemble"):
        load_independent_ensemble(tmp_path / "baseline.zip")
    with pytest.raises(FileNotFoundError, match="not found"):
        load_independent_ensemble(tmp_path / "nothing.zip")


def test_assembling_the_wrong_members_is_one_clear_error(cartpole_members, walker):
    with pytest.raises(ValueError, match="at least 2 members"):
        assemble_ensemble(cartpole_members[:1])
    with pytest.raises(ValueError, match="baseline agents"):
        assemble_ensemble([cartpole_members[0], make_agent("ppo", "ensemble", "CartPole-v1", 0, overrides=TINY)])
    wider = make_agent("ppo", "baseline", "CartPole-v1", 9, overrides=TINY,
                       hyperparameters={**walker.run.hyperparameters["CartPole-v1"], "hidden_sizes": [32]})
    with pytest.raises(ValueError, match=r"differs from member 0 in \['net_arch'\]"):
        assemble_ensemble([cartpole_members[0], wider])
    member = load_checkpoint(walker.member_dir("Walker2d-v5", 0), "Walker2d-v5", "baseline", 0)
    with pytest.raises(ValueError, match="acts on"):
        assemble_ensemble([cartpole_members[0], member.model])
    with pytest.raises(ValueError, match="no normalizer was given"):  # a loaded model holds no VecNormalize
        assemble_ensemble([member.model, member.model])
    model = assemble_ensemble(cartpole_members[:2])
    model.set_env(make_env("CartPole-v1", 1, 0))
    with pytest.raises(ValueError, match="not trained further"):
        model.learn(8)


# ---------------------------------------------------------------------- the study's plumbing


def test_four_of_five_combinations_the_rule_and_the_queue(tmp_path, capsys):
    combos = ens.combinations([0, 1, 2, 3, 4], 4)
    assert combos == [(0, 1, 2, 3), (0, 1, 2, 4), (0, 1, 3, 4), (0, 2, 3, 4), (1, 2, 3, 4)]  # Pi_1 = {1,2,3,4}, ...
    assert {next(iter(set(range(5)) - set(c))) for c in combos} == set(range(5))  # each leaves out another member
    with pytest.raises(ValueError, match="cannot form ensembles of 4"):
        ens.combinations([0, 1, 2], 4)

    paper = section({"envs": APPENDIX_ENVS, "member_seeds": [0, 1, 2, 3, 4], "total_timesteps": None},
                    {"envs": ["HalfCheetah-v5", "Swimmer-v5"], "methods": ["masksembles", "ensemble"],
                     "seeds": [0, 1, 2]}, profile="paper")
    cfg = ens.load_ensembles_config(write_params(tmp_path, "paper", paper))
    hps = cfg.run.hyperparameters
    assert len(cfg.combinations()) == 5 and len(cfg.own_runs()) == 12
    for env_id in cfg.envs:  # a quarter of the interactions, four times the epochs
        steps, epochs = cfg.member_budget(env_id)
        assert steps * 4 == hps[env_id]["total_timesteps"] and epochs == 4 * hps[env_id]["algo"]["n_epochs"]
    assert ens.member_command(cfg, "Walker2d-v5", 3, "/work/resume") == (
        "env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 3 "
        f"{tmp_path}/results/paper/independent/checkpoints/Walker2d-v5/baseline/seed3 --timesteps 250000 "
        f"--hp algo.n_epochs={4 * hps['Walker2d-v5']['algo']['n_epochs']}")
    assert ens.run_command(cfg, "own", "Swimmer-v5", "ensemble", 2) == (
        f".venv/bin/python -m paper_lib.agents.training Swimmer-v5 ensemble 2 {tmp_path}/results/paper/own/checkpoints/"
        "Swimmer-v5/ensemble/seed2 --assignment own")

    (tmp_path / "tiny").mkdir()
    tiny = write_params(tmp_path / "tiny", section=TINY_SECTION)
    ens.main(["--params", str(tiny), "queue"])
    lines = capsys.readouterr().out.splitlines()
    cfg = ens.load_ensembles_config(tiny)
    assert len(lines) == len(cfg.envs) * len(cfg.member_seeds) + 2 * len(cfg.own_runs())  # nothing trained yet
    assert all(" --hp algo.n_epochs=4 " in f"{line} " for line in lines if " baseline " in line)
    assert len(ens.missing_runs(cfg)) == len(lines) and set(ens.missing_runs(cfg)["artifact"]) == {"checkpoint"}

    broken = yaml.safe_load(tiny.read_text())
    broken["ensembles"]["rule"]["budget_fraction"] = 1.5
    tiny.write_text(yaml.safe_dump(broken))
    with pytest.raises(SystemExit) as exit_:
        ens.main(["--params", str(tiny), "missing"])
    assert exit_.value.code == 2
    assert "budget_fraction" in capsys.readouterr().err and tiny.read_text() == yaml.safe_dump(broken)
    del broken["ensembles"]
    tiny.write_text(yaml.safe_dump(broken))
    with pytest.raises(ValueError, match="no `ensembles` section"):
        ens.load_ensembles_config(tiny)


def test_committed_params_hold_the_appendix_rule_and_matrix(tmp_path):
    for profile in ("tiny", "cpu", "paper"):
        (tmp_path / profile).mkdir()
        cfg = ens.load_ensembles_config(write_params(tmp_path / profile, profile))  # params.yaml's own section
        assert (cfg.budget_fraction, cfg.epochs_factor, cfg.ensemble_size) == (0.25, 4, 4)  # appendix B.2
        assert cfg.member_seeds == [0, 1, 2, 3, 4]
        if profile == "tiny":  # members that normalize; own runs whose shared twins the tiny main matrix trains
            assert cfg.run.hyperparameters[cfg.envs[0]]["normalize_obs"]
            assert set(cfg.own_runs()) <= set(cfg.run.runs())
        else:
            assert cfg.envs == APPENDIX_ENVS
            assert (cfg.own_envs, cfg.own_methods, cfg.own_seeds) == (["HalfCheetah-v5", "Swimmer-v5"],
                                                                      ["masksembles", "ensemble"], [0, 1, 2])


def test_an_own_run_trains_with_a_member_ordered_buffer(tmp_path):
    cfg = ens.load_ensembles_config(write_params(tmp_path, section=TINY_SECTION))
    _, kwargs = ens.own_train_args(cfg, "CartPole-v1")
    model = make_agent("ppo", "ensemble", "CartPole-v1", 0, **kwargs).learn(256)
    buffer, k = model.rollout_buffer, model.policy.n_members
    assert isinstance(buffer, MemberOrderedRolloutBuffer) and model.paper_lib_config["assignment"] == "own"
    batch = model.batch_size
    for minibatch in buffer.member_ordered_indices(batch).reshape(-1, batch):
        for j, chunk in enumerate(minibatch.reshape(k, -1)):  # flat index = env * n_steps + step
            assert (member_of_env(chunk // buffer.buffer_size, buffer.n_envs, k) == j).all()


# ------------------------------------------------------------------------------------ notebook


def test_notebook_at_tiny_lists_what_is_missing_and_writes_every_table(tmp_path):
    # The tiny profile's budgets; own vs shared on Walker2d (short episodes), seed 1 left untrained on purpose.
    params = write_params(tmp_path, section=section(
        {"envs": ["Walker2d-v5"], "member_seeds": [0, 1, 2, 3, 4], "total_timesteps": None},
        {"envs": ["Walker2d-v5"], "methods": ["masksembles"], "seeds": [0, 1]}))
    cfg = ens.load_ensembles_config(params)
    from paper_lib.pipeline.stages import train_stage

    ens.main(["--params", str(params), "train", "independent"])
    ens.main(["--params", str(params), "train", "own", "--seed", "0"])
    train_stage(cfg.run, "Walker2d-v5", "masksembles", 0)  # the shared twin, as the main matrix trains it
    def checkpoints() -> dict[Path, int]:  # the members' committed model.zip files (not their resume points)
        return {p: p.stat().st_mtime_ns for p in cfg.independent.results.rglob("seed*/model.zip")}

    trained = checkpoints()
    assert len(trained) == 5
    ens.main(["--params", str(params), "train", "independent"])  # up to date: nothing is retrained
    assert checkpoints() == trained
    assert len(ens.collect_all(cfg, log=lambda line: None)) == 5 + 2  # the shared twin is outside the main matrix
    assert len(ens.evaluate_all(cfg, log=lambda line: None)) == 5 * 2 + 2 * 2
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg"}
    done = subprocess.run([str(BIN / "python"), "-m", "paper_lib.pipeline.notebook_run",  # as its DVC stage runs it
                           "notebooks/11_ensembles.ipynb", str(tmp_path / "11.ipynb"),
                           "-p", "params_file", str(params)],
                          cwd=REPO, env=env, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    tables, figures = cfg.run.tables / "ensembles", cfg.run.figures / "ensembles"
    missing = pd.read_csv(tables / "ensembles_missing.csv")
    assert set(zip(missing["seed"], missing["run"], missing["artifact"])) == {(1, "shared", "checkpoint"),
                                                                              (1, "own", "checkpoint")}
    rewards = pd.read_csv(tables / "ensembles_independent_rewards_long.csv")
    assert (rewards["n_combinations"] == 5).all() and len(rewards) == 4  # combined/single x deterministic/sampled
    episodes = pd.concat([pd.read_csv(cfg.combination_evaluation("Walker2d-v5", m)) for m in cfg.combinations()])
    combined = episodes[(episodes.inference == "combined") & episodes.deterministic]
    vs_paper = pd.read_csv(tables / "ensembles_independent_vs_paper.csv").set_index("quantity")
    per_combination = combined.groupby("combination")["reward"].mean()
    assert len(per_combination) == 5
    assert vs_paper.loc["reward_combined", "ours"] == pytest.approx(per_combination.mean())
    assert vs_paper.loc["reward_combined", "paper"] == pytest.approx(435.59)
    assert np.isnan(vs_paper.loc["rocauc_max_prob", "ours"]) and "discrete" in vs_paper.loc["rocauc_max_prob", "note"]
    auroc = pd.read_csv(tables / "ensembles_independent_auroc_long.csv")
    assert set(auroc["ood_set"]) == {"perturbed", "noise"} and (auroc["n_combinations"] == 5).all()
    comparison = pd.read_csv(tables / "ensembles_own_vs_shared_long.csv")
    assert len(comparison) == 5 and (comparison["n_seeds"] == 1).all()  # 3 rewards (combined x2, single), 2 AUROCs
    np.testing.assert_allclose(comparison["own_minus_shared"], comparison["own"] - comparison["shared"])
    reading = (tables / "ensembles_own_vs_shared_reading.md").read_text()
    assert reading.count("Walker2d-v5, masksembles") == 6  # a line per quantity, and the cost of combining
    independent_reading = (tables / "ensembles_independent_reading.md").read_text()
    assert f"combined inference {per_combination.mean():.1f}" in independent_reading
    assert "shared-buffer Ensemble" not in independent_reading  # this tiny main matrix has no Ensemble run
    for suffix in (".png", ".pdf"):
        assert (figures / f"ensembles_own_vs_shared{suffix}").stat().st_size > 0
    for stem in ("ensembles_independent_rewards", "ensembles_independent_auroc", "ensembles_own_vs_shared"):
        assert "profile 'tiny'" in (tables / f"{stem}.md").read_text().splitlines()[0]


def test_independent_reward_table_keeps_the_envs_in_the_appendix_order():
    from paper_lib.experiments.ensembles_report import independent_reward_table

    summary = pd.DataFrame([dict(env=env, method="independent_ensemble", inference="combined", deterministic=True,
                                 mean=1.0, std=0.5, n_combinations=5) for env in ("Swimmer-v5", "Walker2d-v5")])
    table = independent_reward_table(summary, ["Walker2d-v5", "Swimmer-v5", "MsPacmanNoFrameskip-v4"])
    assert list(table.columns) == ["method", "inference", "actions", "Walker2d-v5", "Swimmer-v5"]
    partial = summary.assign(n_combinations=[1, 5])  # Swimmer with one combination so far, Walker2d complete
    cells = independent_reward_table(partial, ["Walker2d-v5", "Swimmer-v5"]).iloc[0]
    assert (cells["Walker2d-v5"], cells["Swimmer-v5"]) == ("1.0 ± 0.5 (n=5)", "1.0 ± 0.5 (n=1)")


def test_independent_reading_puts_each_appendix_claim_to_the_numbers():
    from paper_lib.experiments.ensembles_report import independent_reading

    vs_paper = pd.DataFrame([
        dict(quantity="reward_combined", env="Swimmer-v5", ours=0.5, ours_std=23.6, n_combinations=5, paper=0.38),
        dict(quantity="reward_single", env="Swimmer-v5", ours=73.2, ours_std=9.2, n_combinations=5, paper=170.64),
        dict(quantity="rocauc_value_std", env="Swimmer-v5", ours=0.49, ours_std=0.1, n_combinations=5, paper=0.26),
        dict(quantity="rocauc_policy_std", env="Swimmer-v5", ours=0.42, ours_std=0.1, n_combinations=5, paper=0.39),
        dict(quantity="reward_combined", env="MsPacmanNoFrameskip-v4", ours=np.nan, ours_std=np.nan,
             n_combinations=pd.NA, paper=1089.2)])  # not trained: no line
    shared = pd.DataFrame([dict(env="Swimmer-v5", ood_set=ood_set, measure="value_std", auroc=auroc, seed=seed)
                           for seed, auroc in enumerate((0.8, 1.0)) for ood_set in ("perturbed", "noise")])
    reward, auroc = independent_reading(vs_paper, shared)
    assert reward.startswith("Swimmer-v5, reward (deterministic, mean over 5 combinations): combined inference 0.5, "
                             "a single member 73.2 (combined - single -72.7, larger than the larger std over "
                             "combinations, 23.6); the paper 0.4 and 170.6")
    assert auroc == ("Swimmer-v5, AUROC on perturbed states: value_std 0.49 independent vs 0.90 shared-buffer "
                     "Ensemble (2 seed(s)).")  # policy_std: no shared-buffer score to put it beside
    assert independent_reading(vs_paper.iloc[4:], shared)[0].startswith("No independent ensemble is complete yet")


def test_one_combination_says_its_reward_std_is_over_episodes():
    """With one of five combinations landed, summarize_rewards' std is over that combination's episodes:
    the table's note and the reading say so instead of calling it a std over combinations."""
    from paper_lib.experiments.ensembles_report import independent_reading, independent_vs_paper

    env = "MsPacmanNoFrameskip-v4"
    summary = pd.DataFrame([dict(env=env, method="independent_ensemble", inference=inference, deterministic=True,
                                 mean=mean, std=std, n_combinations=1)
                            for inference, mean, std in (("combined", 561.0, 116.7), ("single", 480.0, 217.1))])
    auroc = pd.DataFrame([dict(env=env, ood_set="perturbed", measure="value_std", auroc=0.74, auroc_std=np.nan,
                               n_combinations=1)])
    reported = pd.DataFrame([dict(quantity=q, env=env, paper=p) for q, p in
                             (("reward_combined", 1089.2), ("reward_single", 1473.6), ("rocauc_value_std", 0.16))])
    vs_paper = independent_vs_paper(summary, auroc, reported, [env]).set_index("quantity")
    assert vs_paper.loc["reward_combined", "note"] == "one combination so far: ours_std is over its episodes"
    assert vs_paper.loc["rocauc_value_std", "note"] == "one combination so far: no std"
    reward = independent_reading(vs_paper.reset_index(), pd.DataFrame())[0]
    assert "mean over 1 combination)" in reward
    assert "within the larger std over episodes (one combination so far), 217.1" in reward
    assert "std over combinations" not in reward


def test_own_vs_shared_figure_keeps_one_method_order_in_every_panel():
    from paper_lib.experiments.ensembles_report import own_vs_shared_figure

    rows = []
    for quantity, methods in (("reward (deterministic)", ["ensemble", "masksembles"]),
                              ("AUROC value_std", ["masksembles", "ensemble"])):  # rows arrive in either order
        for method in methods:
            for assignment in ("shared", "own"):
                rows.append(dict(env="Swimmer-v5", method=method, seed=0, assignment=assignment,
                                 quantity=quantity, value=1.0))
    fig = own_vs_shared_figure(pd.DataFrame(rows))
    ticks = [[t.get_text() for t in ax.get_xticklabels()] for ax in fig.axes]
    assert ticks[0] == ticks[1] == ["Swimmer\nmasksembles", "Swimmer\nensemble"], ticks


def test_own_vs_shared_reading_says_what_combining_the_members_costs():
    from paper_lib.experiments.ensembles_report import QUANTITIES, own_vs_shared_reading, own_vs_shared_table

    # HalfCheetah's own Ensemble as trained here: members strong alone, their averaged action near zero
    values = {("shared", QUANTITIES[0]): 5270.5, ("shared", QUANTITIES[2]): 5000.0,
              ("own", QUANTITIES[0]): 4.3, ("own", QUANTITIES[2]): 4400.0}
    per_seed = pd.DataFrame([dict(env="HalfCheetah-v5", method="ensemble", seed=0, assignment=a, quantity=q, value=v)
                             for (a, q), v in values.items()])
    lines = own_vs_shared_reading(own_vs_shared_table(per_seed))
    assert ("HalfCheetah-v5, ensemble, combining the members (combined minus single-member deterministic reward): "
            "+270.5 with the shared buffer, -4395.7 with own.") in lines
