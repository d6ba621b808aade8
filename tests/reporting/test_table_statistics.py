"""Intervals and differences of the reward and AUROC tables (notebooks 2 and 3).

Synthetic episodes and replicates check the tables built on the statistics (the statistics themselves:
tests/scoring/test_statistics.py); the committed `cpu` per-run files (read only) check the facts the tables' pairing
rests on.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy.stats import norm
from stable_baselines3.common.vec_env import VecEnvWrapper

from paper_lib.reporting import paper_tables as report
from paper_lib.scoring.statistics import difference_ci, mean_replicates

REPO = Path(__file__).resolve().parents[2]
CPU = REPO / "results" / "cpu"


def _episodes(method: str, inference: str, rewards: dict[int, np.ndarray], members: int | None = None,
              deterministic: bool = False, env: str = "E") -> pd.DataFrame:
    """Evaluation rows as `evaluation.evaluate_rewards` writes them; `members` k: member m plays episodes m, m+k, ..."""
    rows = []
    for seed, values in rewards.items():
        if members is None:
            plan = [(np.nan, values)]
        else:  # member m's episodes come one block after the other, as `_episodes` plays them
            plan = [(m, values[m::members]) for m in range(members)]
        rows += [{"env": env, "method": method, "inference": inference, "deterministic": deterministic,
                  "member": member, "reward": r, "seed": seed} for member, block in plan for r in block]
    return pd.DataFrame(rows)


def _synthetic(n_seeds: int, n_episodes: int, rng: np.random.Generator) -> dict[int, np.ndarray]:
    """Seed means N(100, 10), episodes N(seed mean, 5)."""
    return {s: rng.normal(rng.normal(100, 10), 5, n_episodes) for s in range(n_seeds)}


# ------------------------------------------------------------------------------------------------- rewards
def test_reward_interval_contains_the_mean_and_is_seeded():
    rng = np.random.default_rng(0)
    episodes = pd.concat([_episodes("baseline", "single", _synthetic(3, 10, rng)),
                          _episodes("masksembles", "combined", _synthetic(1, 10, rng))], ignore_index=True)
    intervals = report.reward_intervals(episodes, n_boot=500)
    for _, row in intervals.iterrows():
        cell = episodes[episodes.method == row.method]
        mean = cell.groupby("seed")["reward"].mean().mean()
        assert row.ci_low < mean < row.ci_high
    assert list(intervals.ci_over) == ["seeds, then episodes", "episodes"]
    pd.testing.assert_frame_equal(intervals, report.reward_intervals(episodes, n_boot=500))
    # a cell's interval does not depend on which other cells exist
    alone = report.reward_intervals(episodes[episodes.method == "masksembles"], n_boot=500)
    pd.testing.assert_frame_equal(alone.reset_index(drop=True), intervals.iloc[[1]].reset_index(drop=True))
    assert not intervals.equals(report.reward_intervals(episodes, n_boot=500, seed=1))


def test_more_seeds_shrink_the_interval():
    def width(n_seeds: int) -> float:
        """Seed means spread as N(100, 10) quantiles (the same spread whatever the draw), episodes N(mean, 5)."""
        rng = np.random.default_rng(n_seeds)
        means = 100 + 10 * norm.ppf((np.arange(n_seeds) + 0.5) / n_seeds)
        episodes = _episodes("baseline", "single", {s: rng.normal(m, 5, 10) for s, m in enumerate(means)})
        row = report.reward_intervals(episodes, n_boot=1000).iloc[0]
        return row.ci_high - row.ci_low

    assert width(12) < 0.7 * width(3)
    assert width(48) < 0.7 * width(12)


def test_identical_episodes_paired_difference_is_exactly_zero_and_unpaired_is_not():
    rewards = _synthetic(3, 8, np.random.default_rng(1))
    episodes = pd.concat([_episodes("baseline", "single", rewards),
                          _episodes("masksembles", "combined", rewards),  # same env stream as the baseline
                          _episodes("masksembles", "single", rewards, members=4)],  # member m: its own env
                         ignore_index=True)
    table = report.reward_vs_baseline(episodes, ["baseline", "masksembles"], n_boot=500)
    combined, single = table.set_index("inference").loc["combined"], table.set_index("inference").loc["single"]
    assert combined.pairing == "paired" and (combined.difference, combined.ci_low, combined.ci_high) == (0.0, 0.0, 0.0)
    assert single.pairing == "unpaired" and single.difference == pytest.approx(0.0, abs=1e-9)
    assert single.ci_low < 0 < single.ci_high
    pd.testing.assert_frame_equal(table, report.reward_vs_baseline(episodes, ["baseline", "masksembles"], n_boot=500))


def test_paired_difference_cancels_what_the_episodes_share():
    """Episode i of both runs starts alike: a shared per-episode term cancels in the paired interval."""
    rng = np.random.default_rng(2)
    start = rng.normal(0, 50, 10)  # what the start state does to both runs
    base = {0: 100 + start + rng.normal(0, 1, 10)}
    method = {0: 90 + start + rng.normal(0, 1, 10)}
    paired = pd.concat([_episodes("baseline", "single", base), _episodes("m", "combined", method)], ignore_index=True)
    row = report.reward_vs_baseline(paired, ["baseline", "m"], n_boot=1000).iloc[0]
    assert row.pairing == "paired" and row.ci_high < 0  # 10 lower, clearly, once the start states cancel
    a, b = (mean_replicates(x[0], np.random.default_rng(i), 1000) for i, x in enumerate((method, base)))
    low, high = difference_ci([a], [b], np.random.default_rng(5), "unpaired")
    assert low < 0 < high and row.ci_high - row.ci_low < 0.2 * (high - low)  # unpaired, the 50-point spread swamps it


def test_reward_difference_table_puts_sampled_first_and_states_the_counts():
    rng = np.random.default_rng(3)
    parts = [_episodes(m, i, _synthetic(2, 6, rng), deterministic=d)
             for m, i in (("baseline", "single"), ("ensemble", "combined")) for d in (False, True)]
    long = report.reward_vs_baseline(pd.concat(parts, ignore_index=True), ["baseline", "ensemble"], n_boot=200)
    wide = report.reward_difference_table(long)
    assert list(wide.columns[:7]) == ["env", "method", "inference", "sampled difference", "sampled ci_low",
                                      "sampled ci_high", "sampled baseline"]
    assert wide.columns[7] == "deterministic difference" and wide.pairing.tolist() == ["paired"]
    base = parts[0].groupby("seed").reward.mean().mean()  # the baseline's sampled reward: the claim's margin rests on it
    assert wide["sampled baseline"].iloc[0] == pytest.approx(base)
    assert report.counts_note(long) == "each row: 2 seeds, 12 episodes per action mode; the baseline: 2 seeds, 12 episodes"
    assert report.reward_pairing_note(long).startswith("paired bootstrap for combined inference (1 rows)")
    empty = report.reward_vs_baseline(parts[2], ["baseline", "ensemble"], n_boot=10)  # no baseline: no rows, same columns
    assert empty.empty and list(empty.columns) == report.REWARD_DIFFERENCE_COLUMNS
    assert "sampled difference" in report.reward_difference_table(empty).columns


# ------------------------------------------------------------------------------------------------- AUROC
def _auroc_inputs(member_reps: np.ndarray, detector_reps: np.ndarray, seeds: int = 2):
    rows, reps = [], {}
    for method in ("baseline", "m"):
        for seed in range(seeds):
            measures = {"knn_obs": detector_reps, "mahalanobis_obs": detector_reps - 0.1}
            if method == "m":
                measures["value_std"] = member_reps
            for measure, r in measures.items():
                shifted = r + 0.01 * seed
                rows.append({"env": "E", "method": method, "seed": seed, "ood_set": "perturbed", "measure": measure,
                             "auroc": float(np.mean(shifted))})
                reps[("E", method, seed, "perturbed", measure)] = shifted
    return pd.DataFrame(rows), reps


def test_auroc_vs_detectors_pairs_only_where_resamples_are_shared(monkeypatch):
    monkeypatch.setattr(report, "REPLICATES_SHARE_RESAMPLES", False)  # replicates as older scoring code made them
    r = np.random.default_rng(0).normal(0.8, 0.05, 500)
    metrics, reps = _auroc_inputs(r, r)
    assert report.best_detectors(metrics).to_dict() == {("E", "perturbed"): "knn_obs"}
    row = report.auroc_vs_detectors(metrics, reps, ["baseline", "m"], n_boot=400).iloc[0]
    assert (row.measure, row.detector, row.pairing, row.n_seeds) == ("value_std", "knn_obs", "unpaired", 2)
    assert row.difference == pytest.approx(0.0, abs=1e-12) and row.ci_low < 0 < row.ci_high
    assert "unpaired within a run" in report.detector_pairing_note(pd.DataFrame([row]))
    monkeypatch.setattr(report, "REPLICATES_SHARE_RESAMPLES", True)
    table = report.auroc_vs_detectors(metrics, reps, ["baseline", "m"], n_boot=400)
    row = table.iloc[0]
    assert row.pairing == "paired" and (row.ci_low, row.ci_high) == (0.0, 0.0)
    assert row.family_size == 1 and (row.family_ci_low, row.family_ci_high) == (0.0, 0.0)  # one cell: no correction
    assert report.detector_pairing_note(table).startswith("paired: the same seeds and the same cluster resamples")


def test_auroc_members_vs_baseline_is_unpaired_and_seeded():
    r = np.random.default_rng(1).normal(0.8, 0.01, 500)
    metrics, reps = _auroc_inputs(r + 0.1, r)
    table = report.auroc_members_vs_baseline(metrics, reps, ["baseline", "m"], n_boot=400)
    row = table.iloc[0]
    assert (row.family, row.measure, row.baseline_detector, row.pairing) == ("value", "value_std", "knn_obs", "unpaired")
    assert row.ci_low < row.difference < row.ci_high and row.difference == pytest.approx(0.1)
    pd.testing.assert_frame_equal(table, report.auroc_members_vs_baseline(metrics, reps, ["baseline", "m"], n_boot=400))
    assert report.ci_verdicts(table) == {"above": 1, "below": 0, "undecided": 0}


# ------------------------------------------------------------------------------------------------- committed runs
needs_cpu = pytest.mark.skipif(not (CPU / "scores").is_dir() or not (CPU / "evaluations").is_dir(),
                               reason="the committed cpu results are not in this checkout")


@pytest.fixture(scope="module")
def cpu_cfg(tmp_path_factory):
    """The committed cpu results, their score folders given the provenance records they were committed without
    (the readers refuse scores without one, issue 71): recorded from the committed datasets and checkpoints in a copy."""
    import dataclasses
    from types import SimpleNamespace

    from paper_lib.pipeline.config import load_run_config
    from paper_lib.pipeline.run_results import record_provenance

    root = tmp_path_factory.mktemp("cpu")
    for part in ("checkpoints", "datasets", "evaluations", "scores"):
        shutil.copytree(CPU / part, root / "results" / "cpu" / part)
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["run"] = {"profile": "cpu", **params["profiles"]["cpu"]}
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    cfg = dataclasses.replace(load_run_config(root / "params.yaml"), root=root)
    runs = [(env, method, 0) for env in ("HalfCheetah-v5", "Swimmer-v5")
            for method in ("baseline", "masksembles", "mc_dropout", "mc_dropconnect", "ensemble")]
    record_provenance(cfg, runs)
    return SimpleNamespace(cfg=cfg, results=cfg.results, runs=runs)


@needs_cpu
def test_committed_rewards_pair_combined_inference_with_the_baseline(cpu_cfg):
    from paper_lib.pipeline.run_results import read_evaluations

    episodes = read_evaluations(cpu_cfg.cfg, cpu_cfg.runs)
    long = report.reward_vs_baseline(episodes, [m for _, m, _ in cpu_cfg.runs[:5]], n_boot=300)
    assert len(long) == 2 * 4 * 2 * 2  # envs x member methods x inferences x action modes
    assert set(long.loc[long.inference == "combined", "pairing"]) == {"paired"}
    assert set(long.loc[long.inference == "single", "pairing"]) == {"unpaired"}
    assert ((long.ci_low <= long.difference) & (long.difference <= long.ci_high)).all()
    committed = pd.read_csv(CPU / "tables" / "rewards_long.csv")
    means = committed.set_index(report.REWARD_KEYS)["mean"]
    for row in long.itertuples():
        base = means[(row.env, "baseline", "single", row.actions == "deterministic")]
        assert row.difference == pytest.approx(means[(row.env, row.method, row.inference, row.actions == "deterministic")] - base)


@needs_cpu
def test_committed_replicates_of_two_measures_share_resamples(cpu_cfg):
    """Why REPLICATES_SHARE_RESAMPLES is True: two detectors with nearly the same AUROC on the same states
    move together over the shared cluster resamples (5 OOD configurations)."""
    from paper_lib.pipeline.run_results import read_replicates

    reps = read_replicates(cpu_cfg.cfg, ("HalfCheetah-v5", "baseline", 0))
    a, b = reps[("perturbed", "knn_features")], reps[("perturbed", "mahalanobis_features")]
    assert abs(np.median(a) - np.median(b)) < 0.01 and np.std(a) > 0.1  # alike, and wide: resampling matters
    assert np.corrcoef(a, b)[0, 1] > 0.8
    assert report.REPLICATES_SHARE_RESAMPLES is True


@needs_cpu
def test_committed_pooled_auroc_with_one_seed_is_each_runs_own(cpu_cfg):
    from paper_lib.pipeline.run_results import read_all_replicates, read_scores

    metrics = read_scores(cpu_cfg.cfg, cpu_cfg.runs, "metrics")
    replicates = read_all_replicates(cpu_cfg.cfg, cpu_cfg.runs)
    pooled = report.pooled_auroc(metrics, replicates, n_boot=200)
    merged = pooled.merge(metrics, on=["env", "method", "ood_set", "measure"], suffixes=("", "_run"))
    assert len(merged) == len(metrics) and (pooled.n_seeds == 1).all() and pooled.auroc_seed_std.isna().all()
    assert np.allclose(merged.auroc, merged.auroc_run)
    assert np.allclose(merged.auroc_ci_low, merged.auroc_ci_low_run, atol=1e-6)  # replicates are stored as float32
    assert np.allclose(merged.auroc_ci_high, merged.auroc_ci_high_run, atol=1e-6)
    versus = report.auroc_vs_detectors(metrics, replicates, [m for _, m, _ in cpu_cfg.runs[:5]], n_boot=200)
    assert len(versus) == 2 * 2 * 4 * 3  # envs x OOD sets x member methods x member measures
    assert set(versus.pairing) == {"paired"} and (versus.ci_low <= versus.difference).all() and (versus.difference <= versus.ci_high).all()
    assert set(versus.family_size) == {4 * 3}  # simultaneous over the env's member cells of one OOD set ...
    assert (versus.family_ci_low <= versus.ci_low).all() and (versus.ci_high <= versus.family_ci_high).all()  # ... wider
    assert (versus.family_ci_low < versus.ci_low).any()  # strictly, where the draws allow it


# ------------------------------------------------------------------------------------------------- env seeding
class _StartRecorder(VecEnvWrapper):
    """Keeps the first observation of every episode (the reset, and the auto-reset at each done)."""

    def __init__(self, venv):
        super().__init__(venv)
        self.starts: list[np.ndarray] = []

    def reset(self):
        obs = self.venv.reset()
        self.starts.append(obs[0].copy())
        return obs

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        if dones[0]:
            self.starts.append(obs[0].copy())
        return obs, rewards, dones, infos


class _Policy:
    """Anything with `predict`: zero actions, or uniform random ones from its own generator."""

    def __init__(self, space, seed: int | None):
        self.space, self.rng = space, None if seed is None else np.random.default_rng(seed)

    def predict(self, obs, state=None, episode_start=None, deterministic=False):
        if self.rng is None:
            return np.zeros((len(obs), *self.space.shape), dtype=np.float32), None
        return self.rng.uniform(self.space.low, self.space.high, (len(obs), *self.space.shape)).astype(np.float32), None


@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Swimmer-v5"])
def test_episode_i_starts_alike_whatever_the_policy(env_id):
    """What the paired reward difference rests on: the evaluation env's episode i starts from the same state for
    any policy (its steps draw nothing from the env's generator), and from another state under another seed."""
    from stable_baselines3.common.evaluation import evaluate_policy

    from paper_lib.agents.envs import make_env

    starts = {}
    for name, seed, env_seed in (("zero", None, 10_000), ("random", 1, 10_000), ("other seed", None, 10_001)):
        env = _StartRecorder(make_env(env_id, 1, env_seed, env_kwargs={"max_episode_steps": 50}))
        evaluate_policy(_Policy(env.action_space, seed), env, n_eval_episodes=3, deterministic=True)
        starts[name] = np.stack(env.starts[:3])
        env.close()
    assert np.array_equal(starts["zero"], starts["random"])
    assert not np.array_equal(starts["zero"][0], starts["zero"][1])  # each episode its own start
    assert not np.allclose(starts["zero"], starts["other seed"])


def test_repeated_games_counts_the_distinct_games_of_each_run_and_mode():
    from paper_lib.reporting.paper_tables import repeated_games, repeated_games_note

    def group(method, inference, deterministic, rewards, members=None):
        n = len(rewards)
        return pd.DataFrame({"env": "MsPacmanNoFrameskip-v4", "method": method, "seed": 0, "inference": inference,
                             "deterministic": deterministic, "member": members if members is not None else [np.nan] * n,
                             "reward": rewards, "length": [100 + int(r) for r in rewards]})

    episodes = pd.concat([group("baseline", "single", True, [210.0] * 4),        # one game replayed 4 times
                          group("baseline", "single", False, [1.0, 2.0, 3.0, 4.0]),
                          group("ensemble", "single", True, [5.0] * 4, [0, 1, 0, 1])],  # each member replays its own
                         ignore_index=True)
    repeated = repeated_games(episodes)
    assert repeated[["method", "actions", "episodes", "distinct_games"]].values.tolist() == [
        ["baseline", "deterministic", 4, 1], ["ensemble", "deterministic", 4, 2]]
    note = repeated_games_note(repeated, episodes)
    assert note.startswith("2 of 3 run x mode groups replayed a game (deterministic actions")
    assert "baseline seed 0, single inference, deterministic actions, 1 distinct game(s) in 4 episodes" in note
    distinct = episodes[episodes["deterministic"] == False]  # noqa: E712
    assert repeated_games(distinct).empty
    assert repeated_games_note(repeated_games(distinct), distinct).startswith("Every one of the 1 run x mode groups")


def test_an_ood_set_a_raw_input_detector_separates_is_flagged_per_method():
    """AUROC >= 0.99 of kNN or Mahalanobis on the inputs themselves: the states differ plainly, flagged."""
    from paper_lib.reporting.paper_tables import trivially_separable, trivially_separable_note

    rows = [{"env": "E", "ood_set": "perturbed", "method": m, "seed": s, "measure": d, "auroc": a}
            for m, values in (("x", {"knn_obs": (0.995, 0.999), "mahalanobis_obs": (0.7, 0.7)}),
                              ("y", {"knn_obs": (0.98, 0.99), "mahalanobis_obs": (0.9, 0.9), "value_std": (1.0, 1.0)}))
            for d, pair in values.items() for s, a in enumerate(pair)]
    table = trivially_separable(pd.DataFrame(rows)).set_index("method")
    assert table.loc["x", "detector"] == "knn_obs" and bool(table.loc["x", "trivially_separable"])
    assert table.loc["y", "auroc"] == pytest.approx(0.985) and not table.loc["y", "trivially_separable"]  # value_std is no raw detector
    assert "1 of 2 methods' states" in trivially_separable_note(table.reset_index())
