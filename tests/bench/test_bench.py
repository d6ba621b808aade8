"""The cost benchmark: a tiny end-to-end run, and its bookkeeping (ratios, targets, sampling).

No assertion here depends on how fast anything ran: CI machines are shared and noisy.
"""

from __future__ import annotations

import csv
import math

import pytest

from conftest import TINY
from paper_lib import make_agent
from paper_lib.bench import BenchConfig, Row, build_model, run_benchmark
from paper_lib.bench.__main__ import parse_args
from paper_lib.bench.report import reference_measurement, with_ratios
from paper_lib.bench.timing import interleaved_medians, interleaved_samples

TINY_RUN = dict(envs=("CartPole-v1",), methods=("baseline", "masksembles"), train_steps=256, n_states=32,
                repeats=2, overrides=dict(TINY))


def test_tiny_benchmark_writes_expected_rows(tmp_path):
    rows, markdown = run_benchmark(BenchConfig(**TINY_RUN), tmp_path)
    with open(tmp_path / "bench.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert (tmp_path / "bench.md").read_text() == markdown
    measured = {(r["method"], r["measurement"]) for r in table}
    per_method = {"train_steps_per_s", "rollout_s_per_iter", "update_s_per_iter", "predict_b1", "predict_b32",
                  "act_uncertainty_b1", "uncertainty_b32", "peak_rss_train_mb", "rss_increase_train_mb",
                  "peak_rss_infer_mb", "rss_increase_infer_mb"}
    expected = {("env_only", "env_steps_per_s")} | {(m, name) for m in TINY_RUN["methods"] for name in per_method}
    expected.add(("masksembles", "compiled_act_uncertainty_b1"))  # a member MLP: the compiled one-state call too
    assert measured == expected
    assert len(table) == len(rows) == len(expected)
    for r in table:
        value = float(r["value"])
        assert value >= 0 if r["measurement"].startswith("rss_increase") else value > 0, r
        assert int(r["torch_threads"]) >= 1 and r["machine"]
    base = {r["measurement"]: r for r in table if r["method"] == "baseline"}
    assert float(base["train_steps_per_s"]["ratio_to_baseline"]) == pytest.approx(1.0)
    assert base["act_uncertainty_b1"]["reference"] == "baseline/predict_b1"  # CartPole is discrete: baseline has measures
    train = next(r for r in table if r["method"] == "masksembles" and r["measurement"] == "train_steps_per_s")
    assert float(train["target"]) == 1.15 and train["meets_target"] in {"yes", "no"}
    assert "## CartPole-v1" in markdown and "| train_steps_per_s | steps/s |" in markdown and "## Targets" in markdown
    # the limit column: every inference timing against its arithmetic, nothing else
    limited = {(r["method"], r["measurement"]) for r in table if r["limit"] not in ("", "nan")}
    assert limited == {(m, name) for m in TINY_RUN["methods"]
                       for name in ("predict_b1", "predict_b32", "act_uncertainty_b1", "uncertainty_b32")} | {
                           ("masksembles", "compiled_act_uncertainty_b1")}
    compiled = next(r for r in table if r["measurement"] == "compiled_act_uncertainty_b1")
    assert compiled["reference"] == "baseline/predict_b1" and compiled["macs_per_state"] == next(
        r["macs_per_state"] for r in table if r["method"] == "masksembles" and r["measurement"] == "act_uncertainty_b1")
    for r in table:
        if (r["method"], r["measurement"]) in limited:
            assert float(r["macs_per_state"]) > 0 and float(r["time_over_limit"]) == pytest.approx(
                float(r["value"]) / float(r["limit"]))
    assert "Against the arithmetic limit" in markdown
    # every repetition of every timing, limits included, beside bench.csv
    with open(tmp_path / "bench_timings.csv", newline="") as f:
        timings = list(csv.DictReader(f))
    counts = {}
    for t in timings:
        counts[t["method"], t["measurement"]] = counts.get((t["method"], t["measurement"]), 0) + 1
    for r in table:
        if r["unit"] in ("ms", "steps/s") and r["method"] != "env_only":
            assert counts[r["method"], r["measurement"]] == int(r["samples"]), r
    assert counts["masksembles", "limit:uncertainty_b32"] >= 1
    assert counts["masksembles", "train_steps_per_s"] == 2  # one per measured PPO iteration


def _row(method: str, measurement: str, value: float, unit: str) -> Row:
    return Row("Env", method, measurement, value, unit, 1, "")


def test_ratios_are_cost_ratios_against_the_right_baseline_measurement():
    rows = with_ratios([
        _row("baseline", "train_steps_per_s", 1000.0, "steps/s"),
        _row("ensemble", "train_steps_per_s", 800.0, "steps/s"),  # slower: 1.25x, meets 1.3
        _row("mc_dropout", "train_steps_per_s", 500.0, "steps/s"),  # 2x, misses 1.15
        _row("env_only", "env_steps_per_s", 10000.0, "steps/s"),
        _row("baseline", "predict_b1", 0.2, "ms"),
        _row("masksembles", "act_uncertainty_b1", 0.5, "ms"),  # vs the baseline's predict: 2.5x
        _row("masksembles", "peak_rss_train_mb", 300.0, "MB"),  # no baseline row: no ratio
    ])
    got = {(r.method, r.measurement): r for r in rows}
    assert got["ensemble", "train_steps_per_s"].ratio_to_baseline == pytest.approx(1.25)
    assert got["ensemble", "train_steps_per_s"].meets_target == "yes"
    assert got["mc_dropout", "train_steps_per_s"].meets_target == "no"
    assert got["env_only", "env_steps_per_s"].ratio_to_baseline == pytest.approx(0.1)
    unc = got["masksembles", "act_uncertainty_b1"]
    assert (unc.ratio_to_baseline, unc.reference, unc.target, unc.meets_target) == (pytest.approx(2.5),
                                                                                  "baseline/predict_b1", 1.5, "no")
    assert math.isnan(got["masksembles", "peak_rss_train_mb"].ratio_to_baseline)
    assert got["baseline", "predict_b1"].meets_target == ""  # no target for the reference itself
    assert reference_measurement("uncertainty_b4096") == "predict_b4096"


def test_interleaved_medians_counts_samples():
    calls = {"a": 0, "b": 0}

    def counter(name):
        def fn():
            calls[name] += 1
        return fn

    fns = {name: counter(name) for name in calls}
    assert {name: n for name, (_, n) in interleaved_medians(fns, repeats=3).items()} == {"a": 3, "b": 3}
    # A spent budget still leaves one sample per function, never none, and min_samples where asked.
    assert {name: n for name, (_, n) in interleaved_medians(fns, repeats=3, budget_s=0.0).items()} == {"a": 1, "b": 1}
    assert {name: len(s) for name, s in interleaved_samples(fns, 4, budget_s=0.0, min_samples=3).items()} \
        == {"a": 3, "b": 3}


def test_models_have_equal_sizes_unless_paper_widths():
    equal = BenchConfig(envs=("HalfCheetah-v5",))
    sizes = {m: sum(p.numel() for p in build_model(equal, "HalfCheetah-v5", m).policy.parameters())
             for m in ("baseline", "masksembles", "mc_dropout")}
    assert len(set(sizes.values())) == 1, sizes  # same widths, same parameter count
    paper = BenchConfig(envs=("HalfCheetah-v5",), paper_widths=True)
    assert paper.hidden_sizes("HalfCheetah-v5", "masksembles") == [384, 384]
    assert equal.hidden_sizes("HalfCheetah-v5", "masksembles") == [256, 256]


@pytest.mark.parametrize("method", ["baseline", "ensemble"])
def test_build_model_matches_make_agent_where_widths_agree(method):
    config = BenchConfig(envs=("CartPole-v1",), overrides=dict(TINY))
    ours = build_model(config, "CartPole-v1", method).policy.state_dict()
    theirs = make_agent("ppo", method, "CartPole-v1", overrides=dict(TINY)).policy.state_dict()
    assert {k: v.shape for k, v in ours.items()} == {k: v.shape for k, v in theirs.items()}


def test_command_line():
    config, out = parse_args(["--quick", "--envs", "CartPole-v1", "--methods", "baseline", "ensemble",
                              "--set", "n_steps=16", "--out", "x"])
    assert (config.quick, config.n_states, config.memory, out) == (True, 256, False, "x")
    assert parse_args(["--quick", "--memory", "--states", "8"])[0].memory is True
    assert parse_args(["--states", "8"])[0].n_states == 8 and parse_args([])[0].memory is True
    assert config.algo_kwargs("CartPole-v1")["n_steps"] == 16  # --set wins over --quick
    assert parse_args(["--no-limits"])[0].limits is False and parse_args([])[0].limits is True
    with pytest.raises(ValueError, match="keep it in --methods"):
        BenchConfig(methods=("masksembles",))
    with pytest.raises(ValueError, match="unknown override"):
        BenchConfig(envs=("CartPole-v1",), overrides={"n_step": 1}).algo_kwargs("CartPole-v1")


def test_child_peak_memory_is_its_own_not_the_parents():
    """getrusage's ru_maxrss survives fork + exec: a child would report this process's 1.6 GB."""
    import numpy as np

    from paper_lib.bench.memory import measure_in_child

    ballast = np.ones(200_000_000)  # 1.6 GB resident in the parent
    config = BenchConfig(envs=("CartPole-v1",), methods=("baseline",), overrides=dict(TINY))
    mb = measure_in_child(config, "CartPole-v1", "baseline", "train")
    assert 0 < mb["floor_mb"] <= mb["peak_mb"] < ballast.nbytes / 2**20


def test_the_default_run_gives_the_speed_claim_its_registered_repetitions():
    """params.yaml `preregistration.speed.min_repetitions`: every timing the claim reads, in a default `make bench`."""
    from paper_lib.pipeline.config import read_params
    from paper_lib.reporting.preregistration import Preregistration

    speed = Preregistration.from_params(read_params()).speed
    config = BenchConfig()
    assert config.min_repeats == speed["min_repetitions"] <= config.repeats
    assert all(config.iterations(env) >= speed["min_repetitions"] for env in config.envs)
    assert f"uncertainty_b{config.n_states}" in speed["inference"] and speed["training"] == "train_steps_per_s"
