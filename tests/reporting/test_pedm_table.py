"""PEDM's protocol table (notebook 14) from per-run metrics.csv files laid out as the `pedm` stage writes them.

Synthetic runs in a temporary results tree, read through the same reader as claim 7 (`pedm_stage.read_metrics`):
a baseline and a Masksembles run of two seeds each, whose per-severity means are chosen so the Student-t
interval over the seeds can be computed by hand, each with a steps.npz (written by the stage's own writers) whose
delays and clock are chosen by hand too.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.layout import Layout
from paper_lib.pipeline.pedm_runs import protocol_runs, protocol_settings
from paper_lib.pipeline.pedm_stage import _npz_bytes, steps_arrays
from paper_lib.reporting.pedm_figures import kind_figure
from paper_lib.reporting.pedm_reading import protocol_differences, protocol_reading
from paper_lib.reporting.pedm_table import (NO_RUNS, RUN_COLUMNS, protocol_table,
                                            save_protocol_tables, severity_cells)

REPO = Path(__file__).resolve().parents[2]
ENV = "HalfCheetah-v5"
KINDS = ("bm_factor", "act_factor", "act_offset", "act_noise", "force_vector")
#: Per (method, seed): each scorer's per-severity mean AUROC (PEDM's `mean` rows); the kinds are spread around it.
MEANS = {("baseline", 0): {"pedm": (0.50, 0.90)}, ("baseline", 1): {"pedm": (0.54, 0.92)},
         ("masksembles", 0): {"value_std": (0.60, 0.80), "pedm": (0.52, 0.94)},
         ("masksembles", 1): {"value_std": (0.64, 0.86), "pedm": (0.56, 0.96)}}
T_975_1 = 12.706204736174698  # Student's t, 0.975 quantile, 1 degree of freedom (two seeds)
#: steps.npz: episodes of 16 steps, injected at steps 2 and 8; the step index then scores AUROC 202 / 220 pooled
#: (ID steps 0, 1 and 0-7 against perturbed steps 2-15 and 8-15: 42 + 80 + 80 wins and half-ties of 10 x 22 pairs).
LENGTH, INJECTIONS, CLOCK_AUROC = 16, (2, 8), 202 / 220


def _metrics(method: str, seed: int) -> pd.DataFrame:
    rows = []
    for scorer, severities in MEANS[(method, seed)].items():
        for severity, mean in zip(("minor", "severe"), severities):
            spread = np.linspace(-0.04, 0.04, len(KINDS))  # mean zero: the kinds average to `mean`
            rows += [{"scorer": scorer, "kind": kind, "severity": severity, "auroc": mean + d, "aupr_out": 0.5,
                      "fpr_at_95_tpr": 0.9}
                     for i, (kind, d) in enumerate(zip(KINDS, spread))]
            rows.append({"scorer": scorer, "kind": "mean", "severity": severity, "auroc": mean, "aupr_out": 0.5,
                         "fpr_at_95_tpr": 0.9})
    return pd.DataFrame(rows).assign(env=ENV, method=method, seed=seed)


def _delay(scorer: str, kind_index: int) -> int:
    """The steps from the injection to the first flag, per kind: 3-7 for PEDM, 1-5 for value std."""
    return kind_index + (1 if scorer == "value_std" else 3)


def _steps(method: str, seed: int) -> bytes:
    """steps.npz of a run: one held-out ID episode scored 0 throughout (so the threshold is 0), then per (kind,
    severity) two episodes scored 0 until `_delay` steps after the injection and 1 from there on."""
    scorers = list(MEANS[(method, seed)])
    step = np.arange(LENGTH)
    parts = [pd.DataFrame({"condition": -1, "episode": 0, "step": step, "label": 0, **{s: 0.0 for s in scorers}})]
    conditions = [(kind, severity) for severity in ("minor", "severe") for kind in KINDS]
    for index, (kind, _) in enumerate(conditions):
        for episode, start in enumerate(INJECTIONS):
            parts.append(pd.DataFrame({"condition": index, "episode": episode, "step": step,
                                       "label": (step >= start).astype(int),
                                       **{s: (step >= start + _delay(s, KINDS.index(kind))).astype(float)
                                          for s in scorers}}))
    return _npz_bytes(steps_arrays(pd.concat(parts, ignore_index=True), conditions))


@pytest.fixture
def cfg(tmp_path: Path):
    """The paper profile's config over an empty results tree at `tmp_path`."""
    return dataclasses.replace(load_run_config(REPO / "params.yaml"), root=tmp_path)


def _write_runs(cfg) -> list[tuple[str, str, int]]:
    runs = [(ENV, method, seed) for method, seed in MEANS]
    for run in runs:
        folder = cfg.layout.pedm_dir(*run)
        folder.mkdir(parents=True)
        _metrics(*run[1:]).to_csv(folder / "metrics.csv", index=False)
        (folder / "steps.npz").write_bytes(_steps(*run[1:]))
        (folder / "provenance.json").write_text(json.dumps({"settings": {"epochs": 60, "test_episodes": 20}}))
    return runs


def test_the_table_is_the_mean_over_seeds_with_a_hand_computed_t_interval(cfg, tmp_path):
    runs = protocol_runs(cfg, [*_write_runs(cfg), (ENV, "mc_dropout", 0)])  # a run that has not played: left out
    assert list(runs.columns) == list(RUN_COLUMNS) and len(runs) == 6 * 2 * 6 + 4 * 2 * 6  # and each run's clock
    cells = severity_cells(runs).set_index(["method", "severity", "scorer"])
    pedm = cells.loc[("masksembles", "severe", "pedm")]  # seeds 0.94 and 0.96: mean 0.95, sd 0.01414, se 0.01
    assert pedm.auroc == pytest.approx(0.95) and pedm.n_seeds == 2
    # Student's t gives [0.823, 1.077]: cut to [0, 1], as no AUROC lies above 1
    assert 0.95 + T_975_1 * 0.01 > 1 and (pedm.ci_low, pedm.ci_high) == pytest.approx((0.95 - T_975_1 * 0.01, 1.0))

    table = protocol_table(runs)
    # own measures, then detectors, then the clock (a reference)
    assert list(table.columns) == ["env", "method", "severity", "value_std", "pedm", "clock"]
    assert table[["method", "severity"]].values.tolist() == [["baseline", "minor"], ["baseline", "severe"],
                                                             ["masksembles", "minor"], ["masksembles", "severe"]]
    row = table[(table.method == "masksembles") & (table.severity == "severe")].iloc[0]
    assert row["pedm"] == "0.95 [0.82, 1.00] (n=2)" and row["value_std"] == "0.83 [0.45, 1.00] (n=2)"
    assert row["clock"] == "0.92 [0.92, 0.92] (n=2)"
    assert table[table.method == "baseline"]["value_std"].tolist() == ["", ""]  # a baseline has no measure of its own

    layout = Layout(tmp_path / "out")
    layout.tables.mkdir(parents=True)
    save_protocol_tables(runs, layout.table("pedm_protocol"), layout.pedm_protocol_runs, "paper")
    assert "0.95 [0.82, 1.00] (n=2)" in layout.table("pedm_protocol", "md").read_text()
    assert "runs per env: HalfCheetah-v5 4" in layout.table("pedm_protocol", "md").read_text()
    back = pd.read_csv(layout.pedm_protocol_runs)  # the long form: any cell can be recomputed from it
    means = back[(back.kind == "mean") & (back.scorer == "pedm") & (back.method == "masksembles")]
    assert means[means.severity == "severe"].auroc.mean() == pytest.approx(0.95)


def test_one_seed_shows_no_interval(cfg):
    _write_runs(cfg)
    table = protocol_table(protocol_runs(cfg, [(ENV, "baseline", 0)]))
    assert table["pedm"].tolist() == ["0.50 (n=1)", "0.90 (n=1)"]


def test_delays_the_clock_and_time_matched_aurocs_come_from_the_stored_steps(cfg):
    runs = protocol_runs(cfg, _write_runs(cfg))
    runs = runs.set_index(["method", "seed", "scorer", "kind", "severity"]).sort_index()
    for i, kind in enumerate(KINDS):
        pedm = runs.loc[("masksembles", 1, "pedm", kind, "severe")]
        # held-out scores all 0 (threshold 0, one episode: bound 1/2); flagged `_delay` steps after the injection
        assert (pedm.delay_median, pedm.detected, pedm.false_alarm, pedm.false_alarm_bound) == (i + 3, 1, 0, 0.5)
        assert pedm.auroc == pytest.approx(0.96 + np.linspace(-0.04, 0.04, 5)[i])  # metrics.csv's, untouched
    clock = runs.loc[("baseline", 0, "clock")]
    assert clock["auroc"].to_numpy() == pytest.approx(CLOCK_AUROC) and (clock["auroc_time_matched"] == 0.5).all()
    assert clock["delay_median"].isna().all()
    # PEDM's time-matched AUROC, act_noise (delay 6): per episode 14 resp. 8 perturbed steps, the first 6 tie with
    # the held-out 0 at their step, the rest beat it: (2 * 6 * 0.5 + 8 + 2) / 22
    assert runs.loc[("baseline", 0, "pedm", "act_noise", "minor"), "auroc_time_matched"] == pytest.approx(16 / 22)


def test_a_missing_steps_file_is_one_error_naming_the_stage_to_run_again(cfg):
    runs = _write_runs(cfg)
    (cfg.layout.pedm_dir(ENV, "baseline", 1) / "steps.npz").unlink()
    with pytest.raises(ValueError, match=r"steps.npz .*`dvc repro -s pedm@HalfCheetah-v5-baseline-1`"):
        protocol_runs(cfg, runs)


def test_a_cut_metrics_file_is_one_error_naming_the_stage_to_run_again(cfg):
    runs = _write_runs(cfg)
    path = cfg.layout.pedm_dir(ENV, "masksembles", 1) / "metrics.csv"
    path.write_bytes(path.read_bytes()[:-25])  # cut mid-row
    with pytest.raises(ValueError, match=r"metrics.csv is incomplete \(cut off\?\).*"
                                         r"`dvc repro -s pedm@HalfCheetah-v5-masksembles-1`"):
        protocol_runs(cfg, runs)


def test_a_foreign_metrics_file_is_refused(cfg):
    runs = _write_runs(cfg)
    other = cfg.layout.pedm_dir(ENV, "baseline", 1) / "metrics.csv"
    other.write_bytes((cfg.layout.pedm_dir(ENV, "baseline", 0) / "metrics.csv").read_bytes())  # seed 0's copy
    with pytest.raises(ValueError, match=r"pedm@HalfCheetah-v5-baseline-1"):
        protocol_runs(cfg, runs)


def test_no_runs_give_a_table_that_says_so(cfg, tmp_path):
    runs = protocol_runs(cfg, [(ENV, "baseline", 0)])
    assert runs.empty and list(runs.columns) == list(RUN_COLUMNS)
    layout = Layout(tmp_path / "out")
    layout.tables.mkdir(parents=True)
    table = save_protocol_tables(runs, layout.table("pedm_protocol"), layout.pedm_protocol_runs, "tiny")
    assert table.iloc[0, 0] == NO_RUNS and NO_RUNS in layout.table("pedm_protocol", "md").read_text()
    assert protocol_reading(runs) == ["No run has played PEDM's protocol yet: nothing to read."]


def test_the_prose_is_computed_from_the_runs_and_their_settings(cfg):
    runs = protocol_runs(cfg, _write_runs(cfg))
    settings = protocol_settings(cfg, runs)
    assert settings == {"epochs": [60], "test_episodes": [20]}
    lines = protocol_differences(settings, [ENV, "Walker2d-v5"], ["baseline", "masksembles"])
    text = "\n".join(lines)
    assert "60 epochs, not PEDM's 2000" in text and "20 test episodes per kind and severity, not PEDM's 100" in text
    assert "Walker2d-v5's `foot`" in text and "force -0.1 / -15 N" in text
    minor, severe = protocol_reading(runs)
    # severe: over the 4 runs PEDM averages (0.90 + 0.92 + 0.94 + 0.96) / 4 = 0.93, value_std (0.80 + 0.86) / 2 = 0.83
    assert "best **pedm** 0.93" in severe and "best agent measure value_std 0.83 (over 2 member runs)" in severe
    # delays 3..7 steps per kind for PEDM (median 5), 1..5 for value std (median 3)
    assert ("median delay of PEDM 5 steps (100% of episodes flagged), the shortest value_std's 3 steps (100% of "
            "episodes flagged)") in severe
    # the clock (0.92 in every run) is a reference: never "the best"; only PEDM's severe mean lies above it
    assert "the clock (step index alone) 0.92, above it: pedm" in severe
    assert "the clock (step index alone) 0.92, no scorer above it" in minor and "best **value_std** 0.62" in minor
    # a shorter delay resting on few flagged episodes is not named the shortest
    few = runs.assign(detected=runs["detected"].where(runs["scorer"] != "value_std", 0.2))
    assert "median delay 5 steps (100% of episodes flagged), the shortest, by pedm" in protocol_reading(few)[1]


def test_the_figure_has_a_panel_per_env_and_severity(cfg):
    runs = protocol_runs(cfg, _write_runs(cfg))
    fig = kind_figure(runs, "auroc")
    assert [ax.get_title() for ax in fig.axes] == [f"{ENV}, minor", f"{ENV}, severe"]
    with pytest.raises(ValueError, match="kind_figure draws one of"):
        kind_figure(runs, "aupr")


def test_a_panel_without_values_says_so_and_the_grid_keeps_its_legend(cfg):
    """Swimmer's minor perturbations had no detection delay in any run: its panel is empty, not a crash."""
    runs = protocol_runs(cfg, _write_runs(cfg))
    swimmer = runs.assign(env="Swimmer-v5", delay_median=runs["delay_median"].where(runs["severity"] == "severe"))
    fig = kind_figure(pd.concat([runs, swimmer], ignore_index=True), "delay_median")
    assert [ax.get_title() for ax in fig.axes] == [f"{ENV}, minor", f"{ENV}, severe", "Swimmer-v5, minor",
                                                   "Swimmer-v5, severe"]
    empty = fig.axes[2]
    assert [t.get_text() for t in empty.texts] == ["no run has a\nmedian delay (steps)"] and not empty.patches
    assert not empty.get_yticks().size and not empty.get_xticks().size  # no axis scale to misread as values
    assert all(ax.patches for ax in fig.axes[:2] + fig.axes[3:])  # bars everywhere else
    assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
