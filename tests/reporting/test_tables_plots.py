"""Atomic writing, tables and figures on tiny inputs."""

import json

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from paper_lib.common.io import atomic_path, save_npz_atomic, write_json_atomic, write_text_atomic
from paper_lib.reporting import plots, tables


# ---------------------------------------------------------------- io
def test_atomic_path_failure_leaves_nothing(tmp_path):
    target = tmp_path / "sub" / "table.csv"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half a table")
            raise RuntimeError("crash mid-write")
    assert not target.exists()
    assert list((tmp_path / "sub").iterdir()) == []  # temp file removed too


def test_atomic_path_failure_keeps_old_file(tmp_path):
    target = tmp_path / "t.txt"
    write_text_atomic(target, "old\n")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("new")
            raise RuntimeError
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["t.txt"]


def test_atomic_writers_roundtrip(tmp_path):
    write_text_atomic(tmp_path / "a" / "b.txt", "héllo\n")
    assert (tmp_path / "a" / "b.txt").read_text(encoding="utf-8") == "héllo\n"
    write_json_atomic(tmp_path / "m.json", {"b": 1, "a": [1.5]})
    assert json.loads((tmp_path / "m.json").read_text()) == {"a": [1.5], "b": 1}
    save_npz_atomic(tmp_path / "x.npz", obs=np.arange(6).reshape(2, 3), act=np.ones(2))
    with np.load(tmp_path / "x.npz") as z:
        np.testing.assert_array_equal(z["obs"], np.arange(6).reshape(2, 3))
        assert sorted(z.files) == ["act", "obs"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "m.json", "x.npz"]
    # Same permissions as a file written with open() (mkstemp alone would give 0o600).
    (tmp_path / "plain.txt").write_text("x")
    assert (tmp_path / "m.json").stat().st_mode == (tmp_path / "plain.txt").stat().st_mode
    with pytest.raises(ValueError, match="must end in '.npz'"):
        save_npz_atomic(tmp_path / "x.npy", a=np.ones(1))


# ---------------------------------------------------------------- tables
RESULTS = pd.DataFrame(
    {
        "env": ["Ant", "Ant", "Ant", "Ant", "Swimmer"],
        "method": ["ms", "ms", "drop", "drop", "ms"],
        "seed": [0, 1, 0, 1, 0],
        "reward": [1.0, 3.0, 10.0, 14.0, 5.0],
    }
)


def test_mean_std_values_and_strings():
    num = tables.mean_std_values(RESULTS, "env", "method", "reward")
    assert num.loc["Ant", ("mean", "ms")] == 2.0
    assert num.loc["Ant", ("std", "drop")] == pytest.approx(np.sqrt(8.0))  # ddof=1: (2^2 + 2^2) / 1
    assert num.loc["Swimmer", ("n", "ms")] == 1 and np.isnan(num.loc["Swimmer", ("std", "ms")])
    text = tables.mean_std_table(RESULTS, "env", "method", "reward", float_format="%.2f")
    assert list(text.columns) == ["ms", "drop"]  # first-appearance order
    assert text.loc["Ant", "ms"] == "2.00 ± 1.41"
    assert text.loc["Ant", "drop"] == "12.00 ± 2.83"
    assert text.loc["Swimmer", "ms"] == "5.00"  # one seed: no spread to show
    assert text.loc["Swimmer", "drop"] == ""  # never run


def test_mean_std_errors():
    with pytest.raises(ValueError, match=r"missing column\(s\) \['score'\]"):
        tables.mean_std_table(RESULTS, "env", "method", "score")
    with pytest.raises(ValueError, match="non-numeric"):
        tables.mean_std_values(RESULTS.assign(reward=["a", 1, 2, 3, 4]), "env", "method", "reward")


def test_save_table_writes_three_files_with_caption(tmp_path):
    df = pd.DataFrame({"measure": ["value_unc", "a|b"], "auroc": [0.912345, 0.5], "n": [3, 4]})
    paths = tables.save_table(df, tmp_path / "out" / "roc.auc", caption="AUROC 95% CI, OOD = positive")
    assert sorted(p.name for p in paths.values()) == ["roc.auc.csv", "roc.auc.md", "roc.auc.tex"]
    csv = pd.read_csv(paths["csv"])
    assert csv["auroc"].iloc[0] == 0.912345  # CSV keeps full precision
    md = paths["md"].read_text().splitlines()
    assert md[0] == "AUROC 95% CI, OOD = positive"
    assert any("0.912" in line and "0.9123" not in line for line in md)
    assert any(r"a\|b" in line for line in md)  # pipe escaped, table not broken
    tex = paths["tex"].read_text()
    assert r"\caption{AUROC 95\% CI, OOD = positive}" in tex
    assert r"\toprule" in tex and r"\midrule" in tex and r"\bottomrule" in tex
    assert r"value\_unc & 0.912 & 3" in tex
    # Markdown fallback (no tabulate) holds the same cells.
    shown = tables._format_cells(df, "%.3f")
    fallback = tables._markdown_table(shown, [False, True, True])
    assert fallback.splitlines()[1] == "|:---|---:|---:|"
    assert "| value_unc | 0.912 | 3 |" in fallback


def test_a_table_differing_in_the_last_bits_writes_the_same_csv_bytes(tmp_path):
    """Another CPU moves a computed interval by an ulp (4724.213155629166 vs ...167 seen across machines)."""
    value = 4724.213155629166
    here = pd.DataFrame({"env": ["Ant-v5", "Swimmer-v5"], "ci_high": [value, np.nan], "n_seeds": [3, 1],
                         "steps": [1000448.0, 2e-30]})
    there = here.assign(ci_high=[np.nextafter(value, np.inf), np.nan])
    assert here.ci_high[0] != there.ci_high[0]
    assert tables.csv_text(here) == tables.csv_text(there)
    tables.save_table(here, tmp_path / "a", caption="A table.")
    tables.save_table(there, tmp_path / "b", caption="A table.")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    back = pd.read_csv(tmp_path / "a.csv")
    assert back.ci_high[0] == pytest.approx(value, rel=1e-12) and np.isnan(back.ci_high[1])
    assert back.steps.tolist() == [1000448.0, 2e-30] and back.n_seeds.dtype == np.int64  # ints and dtypes kept


def test_save_table_index_and_errors(tmp_path):
    text = tables.mean_std_table(RESULTS, "env", "method", "reward")
    paths = tables.save_table(text, tmp_path / "rew", caption="Reward")
    assert paths["csv"].read_text().splitlines()[0] == "env,ms,drop"  # named index becomes a column
    assert r"2.0 $\pm$ 1.4" in paths["tex"].read_text()
    with pytest.raises(ValueError, match="caption"):
        tables.save_table(text, tmp_path / "x", caption=" ")
    with pytest.raises(ValueError, match="float_format"):
        tables.save_table(text, tmp_path / "x", caption="c", float_format="{:.3f}")
    assert not any(p.name.startswith("x") for p in tmp_path.iterdir())


def test_a_cell_whose_interval_rests_on_one_seed_says_so_itself(tmp_path):
    df = pd.DataFrame({"env": ["Ant", "MsPacman", "Seaquest"], "auroc": [0.8123, 0.61, 0.5],
                       "auroc_ci_low": [0.78, 0.55, np.nan], "auroc_ci_high": [0.84, 0.66, np.nan], "n_seeds": [3, 1, 1]})
    cells = tables.interval_cells(df, "auroc", "auroc_ci_low", "auroc_ci_high")
    assert cells.tolist() == ["0.812 [0.780, 0.840]", "0.610 [0.550, 0.660]\u00b9", "0.500\u00b9"]
    paths = tables.save_table(df, tmp_path / "t", caption="AUROC (1 or 3 seeds).",
                              intervals={"auroc": ("auroc_ci_low", "auroc_ci_high")})
    md = paths["md"].read_text()
    assert md.splitlines()[0] == f"AUROC (1 or 3 seeds). {tables.ONE_SEED_NOTE}."
    assert "auroc [95% CI]" in md and "0.610 [0.550, 0.660]\u00b9" in md and "auroc_ci_low" not in md
    assert r"0.610 [0.550, 0.660]$^{1}$" in paths["tex"].read_text()
    assert pd.read_csv(paths["csv"]).columns.tolist() == df.columns.tolist()  # code reads the three columns apart
    several = tables.save_table(df[df.n_seeds == 3], tmp_path / "s", caption="AUROC.",
                                intervals={"auroc": ("auroc_ci_low", "auroc_ci_high")})
    assert several["md"].read_text().splitlines()[0] == "AUROC."  # no cell of one seed: no footnote
    empty = tables.save_table(df.iloc[:0], tmp_path / "e", caption="AUROC.",
                              intervals={"auroc": ("auroc_ci_low", "auroc_ci_high")})
    assert "auroc [95% CI]" in empty["md"].read_text()


# ---------------------------------------------------------------- plots
def _data_lines(ax) -> list:
    """Lines that draw data (seaborn also parks empty legend proxies on the axes)."""
    return [ln for ln in ax.lines if len(ln.get_xdata()) > 0]


def _roc_df() -> pd.DataFrame:
    rows = []
    for env in ["Ant", "Swimmer"]:
        for method in ["ms", "drop", "ens"]:
            for measure in ["value", "policy"]:
                for fpr, tpr in [(0, 0), (0, 0.5), (0.5, 0.9), (1, 1)]:
                    rows.append(dict(env=env, method=method, measure=measure, fpr=fpr, tpr=tpr))
    return pd.DataFrame(rows)


def test_roc_curves_panels_and_lines():
    fig = plots.roc_curves(_roc_df())
    assert isinstance(fig, Figure) and len(fig.axes) == 2
    for ax in fig.axes:
        lines = _data_lines(ax)
        assert len(lines) == 3 * 2 + 1  # method x measure, plus the chance diagonal
        np.testing.assert_array_equal(lines[-1].get_xydata(), [[0, 0], [1, 1]])
        assert ax.get_legend() is None
    (legend,) = fig.legends  # one legend for the grid, naming every method and measure
    assert {"ms", "drop", "ens", "value", "policy"} <= {t.get_text() for t in legend.get_texts()}


def test_roc_curves_wrap_eight_envs_into_two_rows():
    df = pd.concat([_roc_df().assign(env=lambda d, i=i: d["env"] + str(i)) for i in range(4)])  # 2 envs x 4
    fig = plots.roc_curves(df)
    rows = {round(ax.get_position().y0, 3) for ax in fig.axes}
    assert len(fig.axes) == 8 and len(rows) == 2


def test_uncertainty_over_time_red_boundary():
    df = pd.DataFrame({
        "step": np.tile(np.arange(10), 2), "score": np.arange(20.0),
        "method": np.repeat(["ms", "drop"], 10), "phase": np.tile(["id"] * 6 + ["ood"] * 4, 2),
    })
    fig = plots.uncertainty_over_time(df)
    (ax,) = fig.axes
    lines = _data_lines(ax)
    assert len(lines) == 3
    vline = lines[-1]
    assert vline.get_color() == "red" and list(vline.get_xdata()) == [5.5, 5.5]
    fig.canvas.draw()  # the legend sits beside the axes, off the traces
    legend, axes_box = ax.get_legend().get_window_extent(), ax.get_window_extent()
    assert legend.x0 >= axes_box.x1
    with pytest.raises(ValueError, match="ID steps must precede OOD"):
        plots.uncertainty_over_time(df.assign(phase=np.tile(["ood"] * 5 + ["id"] * 5, 2)))
    with pytest.raises(ValueError, match="phase must take"):
        plots.uncertainty_over_time(df.assign(phase="id"))


def test_training_curves_mean_and_band():
    df = pd.DataFrame({
        "timesteps": np.tile([0, 100, 200], 4), "reward": [0, 1, 2, 2, 3, 4, 10, 10, 10, 20, 20, 20.0],
        "method": np.repeat(["ms", "ms", "base", "base"], 3), "seed": np.repeat([0, 1, 0, 1], 3), "env": "Ant",
    })
    fig = plots.training_curves(df)
    (ax,) = fig.axes
    lines = _data_lines(ax)
    assert len(lines) == 2
    np.testing.assert_allclose(lines[0].get_ydata(), [1, 2, 3])  # mean over the two ms seeds
    assert len(ax.collections) == 2  # one std band per method


def test_normalized_bars_count_and_reference():
    df = pd.DataFrame({"perturbation": ["none", "black", "white"] * 2, "method": np.repeat(["ms", "drop"], 3),
                       "ratio": [1.0, 2.0, 3.0, 1.0, 1.5, 0.5]})
    fig = plots.normalized_bars(df)
    (ax,) = fig.axes
    bars = [bar for container in ax.containers for bar in container]
    assert len(bars) == 6
    assert [b.get_height() for b in bars] == [1.0, 2.0, 3.0, 1.0, 1.5, 0.5]
    assert any(list(ln.get_ydata()) == [1.0, 1.0] for ln in _data_lines(ax))


def test_pareto_scatter_highlights_front():
    df = pd.DataFrame({"reward": [1.0, 2, 3, 4, 5], "auroc": [0.9, 0.5, 0.8, 0.6, 0.7],
                       "method": ["ms", "ms", "drop", "drop", "drop"], "is_pareto": [True, False, True, False, True]})
    fig = plots.pareto_scatter(df)
    (ax,) = fig.axes
    assert [len(c.get_offsets()) for c in ax.collections] == [5, 3]
    with pytest.raises(ValueError, match="boolean"):
        plots.pareto_scatter(df.assign(is_pareto=[1, 0, 1, 0, 1]))


def test_plot_missing_columns():
    with pytest.raises(ValueError, match=r"missing column\(s\) \['env'\]"):
        plots.roc_curves(_roc_df().drop(columns="env"))


def test_save_figure_writes_identical_png_and_pdf(tmp_path):
    first = plots.save_figure(plots.roc_curves(_roc_df()), tmp_path / "figs" / "roc")
    assert first["png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert first["pdf"].read_bytes()[:5] == b"%PDF-"
    png, pdf = first["png"].read_bytes(), first["pdf"].read_bytes()
    assert len(png) > 1000 and len(pdf) > 1000
    second = plots.save_figure(plots.roc_curves(_roc_df()), tmp_path / "figs" / "roc")
    assert second["png"].read_bytes() == png
    assert second["pdf"].read_bytes() == pdf
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == ["roc.pdf", "roc.png"]


def _figures_with_random_draws() -> dict[str, Figure]:
    """Every figure that draws at random: strip-plot jitter and seaborn's bootstrap intervals (several runs a cell)."""
    from paper_lib.experiments.ensembles_report import own_vs_shared_figure
    from paper_lib.guard.report import false_alarm_figure, trace_figure

    seeds = range(3)
    aurocs = pd.DataFrame([dict(env=env, method=method, score=score, auroc=0.5 + 0.1 * seed + 0.01 * len(score))
                           for env in ("Walker2d-v5", "Swimmer-v5") for method in ("baseline", "masksembles")
                           for score in ("value_std", "knn_obs") for seed in seeds])
    pairs = pd.DataFrame([dict(env="Swimmer-v5", method=method, seed=seed, assignment=assignment,
                               quantity="reward (deterministic)", value=10.0 * seed + len(assignment))
                          for method in ("masksembles", "ensemble") for assignment in ("shared", "own") for seed in seeds])
    alarms = pd.DataFrame([dict(env="Walker2d-v5", method=method, score="value_std", guard=guard, alpha=0.05,
                                id_false_alarm_rate=0.01 * (seed + 1))
                           for guard in ("state", "window", "cusum") for method in ("baseline", "masksembles")
                           for seed in seeds])
    traces = pd.DataFrame([dict(env="Walker2d-v5", method=method, score="value_std", step=step, statistic=step + seed,
                                threshold=10.0, change_step=5) for method in ("baseline", "masksembles")
                           for seed in seeds for step in range(12)])
    return {"score_aurocs": plots.score_aurocs(aurocs), "own_vs_shared": own_vs_shared_figure(pairs),
            "false_alarms": false_alarm_figure(alarms), "traces": trace_figure(traces)}


def test_figures_that_draw_at_random_redraw_byte_for_byte_and_leave_the_global_rng_alone(tmp_path):
    drawn = []
    for global_seed in (1, 2):  # whatever state the caller left NumPy's global RNG in
        np.random.seed(global_seed)
        figures = _figures_with_random_draws()
        assert np.random.randint(1 << 30) == np.random.RandomState(global_seed).randint(1 << 30), \
            "a figure drew from the caller's global RNG stream"
        drawn.append({name: plots.save_figure(fig, tmp_path / f"{name}_{global_seed}")["png"].read_bytes()
                      for name, fig in figures.items()})
    for name in drawn[0]:
        assert drawn[0][name] == drawn[1][name], f"{name} differs between two draws of the same data"


def test_timeline_and_image_grid():
    df = pd.DataFrame({"step": np.tile(np.arange(6), 3), "score": np.arange(18.0) / 18,
                       "measure": np.repeat(["value_std", "knn_obs", "policy_std"], 6),
                       "panel": np.repeat(["members", "member-free", "members"], 6)})
    fig = plots.timeline(df, event_step=2.5, reference=0.95)
    assert [ax.get_title() for ax in fig.axes] == ["members", "member-free"]
    lines = _data_lines(fig.axes[0])
    assert len(lines) == 2 + 2  # two measures, the event line, the reference line
    assert any(list(ln.get_xdata()) == [2.5, 2.5] and ln.get_color() == "red" for ln in lines)
    images = [np.zeros((4, 6, 3), dtype=np.uint8), np.full((4, 6), 255, dtype=np.uint8), np.zeros((4, 6), np.uint8)]
    fig = plots.image_grid(images, ["a", "b", "c"], ncols=2)
    shown = [ax for ax in fig.axes if ax.images]
    assert len(fig.axes) == 4 and len(shown) == 3 and [ax.get_title() for ax in shown] == ["a", "b", "c"]
    with pytest.raises(ValueError, match="one title per image"):
        plots.image_grid(images, ["a"])


def test_show_figure_displays_the_saved_png(tmp_path, monkeypatch):
    shown = []
    monkeypatch.setattr("IPython.display.display", lambda obj: shown.append(obj))
    plots.show_figure(plots.roc_curves(_roc_df()), tmp_path / "roc")
    assert shown[0].data == (tmp_path / "roc.png").read_bytes()
    plots.show_figure(plots.roc_curves(_roc_df()))  # no stem: shown, not saved
    assert shown[1].data[:8] == b"\x89PNG\r\n\x1a\n" and sorted(p.name for p in tmp_path.iterdir()) == ["roc.pdf", "roc.png"]
    with pytest.raises(ValueError, match="matplotlib Figure"):
        plots.show_figure("not a figure")


# ---------------------------------------------------------------- report helpers for partial profiles
def test_seeds_per_cell_and_coverage_captions():
    from types import SimpleNamespace

    from paper_lib.reporting import paper_tables as report

    df = pd.DataFrame({"env": ["A", "A", "A", "B"], "method": ["m", "m", "n", "m"], "seed": [0, 1, 0, 0]})
    assert report.seeds_per_cell(df[df.env == "B"], ["env", "method"]) == "1 seed per cell"
    assert report.seeds_per_cell(df.assign(seed=[0, 1, 0, 1]).iloc[:2], ["env", "method"]) == "2 seeds per cell"
    assert report.seeds_per_cell(df, ["env", "method"]) == "seeds per cell: A 1 to 2, B 1"
    cfg = SimpleNamespace(profile="p", runs=lambda: [("A", m, s) for m in ("m", "n") for s in (0, 1)])
    assert report.coverage(cfg, cfg.runs()) == "profile 'p': all 4 runs"
    assert report.coverage(cfg, [("A", "m", 0)]).startswith("profile 'p': 1 of its 4 runs (the missing ones")
    assert report.coverage(cfg, [("A", "m", 0), ("A", "m", 1)], ["m"]) == "profile 'p': all 2 m runs"


def test_reward_table_marks_cells_with_fewer_seeds():
    from paper_lib.reporting.paper_tables import reward_table

    summary = pd.DataFrame({"env": ["A", "A"], "method": ["baseline", "masksembles"], "inference": ["single", "combined"],
                            "deterministic": [True, True], "mean": [10.0, 8.0], "std": [1.0, 2.0], "n_seeds": [3, 1]})
    table = reward_table(summary, ["baseline", "masksembles"])
    assert list(table["A"]) == ["10.0 ± 1.0 (n=3)", "8.0 ± 2.0 (n=1)"]
    assert list(reward_table(summary.assign(n_seeds=3), ["baseline", "masksembles"])["A"]) == ["10.0 ± 1.0", "8.0 ± 2.0"]


def test_roc_on_grid_is_the_reachable_tpr():
    from paper_lib.pipeline.run_results import roc_on_grid
    from paper_lib.scoring.metrics import roc_points

    rng = np.random.default_rng(0)
    id_s, ood_s = rng.normal(0, 1, 300), rng.normal(1, 1, 200)
    roc = roc_points(id_s, ood_s).assign(measure="m", ood_set="perturbed")
    grid = roc_on_grid(roc, np.array([0.0, 0.1, 0.5, 1.0]))
    for fpr, tpr in zip(grid["fpr"], grid["tpr"]):  # the best TPR of any threshold whose FPR is at most fpr
        thresholds = np.concatenate([[np.inf], np.sort(np.concatenate([id_s, ood_s]))[::-1]])
        best = max((ood_s >= t).mean() for t in thresholds if (id_s >= t).mean() <= fpr)
        assert tpr == pytest.approx(best)
    assert list(grid["tpr"]) == sorted(grid["tpr"]) and grid["tpr"].iloc[-1] == 1.0


def test_protocol_note_describes_the_states_as_collected():
    from paper_lib.reporting.paper_tables import protocol_note

    rows = [{"ood_set": o, "env": e, "method": "m", "seed": 0, "protocol": p, "actions": "sampled actions, vote inference",
             "n_ood": n, "n_ood_clusters": c, "n_id": 1000, "n_id_clusters": 10}
            for e, p, n, c in (("A", "main", 5000, 50), ("B", "appendix", 2000, 5)) for o in ("perturbed", "noise")]
    note = protocol_note(pd.DataFrame(rows))
    assert note == ("states as collected: main-text protocol (section 5) with sampled actions, vote inference for 1 run: "
                    "5000 OOD states from 50 distinct conditions and 1000 held-out ID states from 10 episodes per run; "
                    "appendix G protocol with sampled actions, vote inference for 1 run: 2000 OOD states from 5 "
                    "distinct conditions and 1000 held-out ID states from 10 episodes per run")
    # envs of one protocol with other numbers of distinct conditions (MsPacman's 50 draws are 3 mazes): each env's
    mixed = pd.DataFrame(rows).assign(protocol="main", n_ood=5000)
    mixed.loc[mixed.env == "B", "n_ood_clusters"] = 3
    assert "5000 OOD states from distinct conditions per env (A 50, B 3) and" in protocol_note(mixed)
    assert protocol_note(pd.DataFrame(rows).drop(columns="protocol")) == "collection protocol not recorded"


def test_training_curves_wrap_into_rows_of_four():
    envs = [f"env{i}" for i in range(6)]
    df = pd.DataFrame({"timesteps": np.tile([0, 100], 6), "reward": np.arange(12.0), "method": "ms", "seed": 0,
                       "env": np.repeat(envs, 2)})
    fig = plots.training_curves(df)
    assert [ax.get_title() for ax in fig.axes] == envs  # two unused cells of the 2 x 4 grid are removed
    rows = sorted({round(ax.get_position().y0, 3) for ax in fig.axes})
    assert len(rows) == 2 and sum(ax.get_position().y0 > rows[0] for ax in fig.axes) == 4


def test_performance_profiles_draw_a_curve_per_method_and_bands_only_where_there_are_seeds():
    from paper_lib.reporting.aggregates import profiles_by_env_family

    rows = [{"env": env, "method": m, "seed": s, "auroc": base + 0.1 * s + (0.2 if m == "ms" else 0.0)}
            for env, base, seeds in (("HalfCheetah-v5", 0.3, (0, 1, 2)), ("MsPacmanNoFrameskip-v4", 0.5, (0,)))
            for m in ("ms", "drop") for s in seeds]
    profiles = profiles_by_env_family(pd.DataFrame(rows), "auroc", ["ms", "drop"], n_boot=50)
    fig = plots.performance_profiles(profiles, "AUROC", reference=0.5)
    mujoco, atari = fig.axes
    assert mujoco.get_title().startswith("MuJoCo (3 seeds x 1 envs") and "no band" in atari.get_title()
    assert len(mujoco.collections) == 2 and len(atari.collections) == 0  # bands: MuJoCo's two methods, none for Atari
    curves = [ln for ln in _data_lines(mujoco) if len(ln.get_xdata()) > 2]
    expected = profiles[(profiles.family == "MuJoCo") & (profiles.method == "ms")]
    np.testing.assert_array_equal(curves[0].get_ydata(), expected["fraction"])
    assert any(list(ln.get_xdata()) == [0.5, 0.5] for ln in _data_lines(mujoco))  # chance
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["ms", "drop"]


def test_auroc_with_intervals_draws_one_panel_per_env_and_an_error_bar_per_cell():
    """The site's headline figure: a panel per env, per method a dot per measure with its interval; NaN bounds pass."""
    import pandas as pd

    from paper_lib.reporting.plots import auroc_with_intervals

    rows = [{"env": env, "method": method, "measure": measure, "auroc": 0.7, "auroc_ci_low": 0.6 if env == "A" else None,
             "auroc_ci_high": 0.8 if env == "A" else None}
            for env in ("A", "B", "C") for method in ("ms", "mcd") for measure in ("value_std", "policy_std")]
    fig = auroc_with_intervals(pd.DataFrame(rows))
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert [ax.get_title() for ax in panels] == ["A", "B", "C"]
    assert all(len(ax.containers) == 2 for ax in panels)  # one errorbar container per measure
    assert [t.get_text() for t in panels[0].get_xticklabels()] == ["ms", "mcd"]
