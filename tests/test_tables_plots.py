"""Atomic writing, tables and figures on tiny inputs."""

import json

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from paper_lib import plots, tables
from paper_lib.io import atomic_path, save_npz_atomic, write_json_atomic, write_text_atomic


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
    assert fig.axes[0].get_legend() is None and fig.axes[1].get_legend() is not None


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
