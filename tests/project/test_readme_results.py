"""README and docs numbers are the pipeline's: `scripts/readme_results.py` pastes them, and the files match its output."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "scripts"))

import readme_results  # noqa: E402

from paper_lib.pipeline.layout import Layout  # noqa: E402

#: Every file the script pastes into, and its marker pairs.
PASTED = {
    readme_results.README: [(readme_results.HEADLINE_START, readme_results.HEADLINE_END)],
    readme_results.RESULTS_PAGE: [(readme_results.START, readme_results.END)],
    readme_results.BENCH_PAGE: [(readme_results.BENCH_START, readme_results.BENCH_END),
                                (readme_results.LIMITS_START, readme_results.LIMITS_END)],
    readme_results.DEVIATIONS_PAGE: [(readme_results.PROBES_START, readme_results.PROBES_END)],
}


@pytest.fixture(scope="module")
def profile() -> str:
    return readme_results.active_profile()


def block(text: str, start: str, end: str) -> str:
    """What lies between a marker pair (a missing pair fails the test)."""
    assert text.count(start) == 1 and text.count(end) == 1, f"expected one {start} ... {end} pair"
    return text.split(start, 1)[1].split(end, 1)[0].strip()


def copy_inputs(profile: str, to: Path) -> None:
    """The committed README, docs pages and the results they are pasted from, into `to`."""
    shutil.copy(REPO / "README.md", to / "README.md")
    shutil.copytree(REPO / "docs", to / "docs")
    for part in (f"results/{profile}/tables", "results/bench"):
        shutil.copytree(REPO / part, to / part)
    shutil.copy(REPO / f"results/{profile}/runs.md", to / f"results/{profile}/runs.md")
    (to / readme_results.PROBES_CSV).parent.mkdir(parents=True)
    shutil.copy(REPO / readme_results.PROBES_CSV, to / readme_results.PROBES_CSV)


def blank_blocks(root: Path) -> None:
    """Every marker pair under `root` emptied to "stale", so that a paste the script no longer makes shows."""
    for path, pairs in PASTED.items():
        text = (root / path).read_text()
        for start, end in pairs:
            if start in text and end in text:
                text = readme_results.paste(text, start, end, "stale", path)
        (root / path).write_text(text)


def test_bench_table_marks_met_targets_and_names_differing_ones(tmp_path: Path):
    rows = [("HalfCheetah-v5", m, "train_steps_per_s", r, t, meets)
            for m, r, t, meets in [("masksembles", 1.1, 1.15, "yes"), ("mc_dropout", 1.3, 1.15, "no"),
                                   ("mc_dropconnect", 2.0, 1.15, "no"), ("ensemble", 1.2, 1.3, "yes")]]
    csv = tmp_path / "bench.csv"
    pd.DataFrame(rows, columns=["env_id", "method", "measurement", "ratio_to_baseline", "target",
                                "meets_target"]).to_csv(csv, index=False)
    line = next(l for l in readme_results.bench_table(csv).splitlines() if l.startswith("| HalfCheetah training"))
    assert line == "| HalfCheetah training | **1.10x** | 1.30x | 2.00x | **1.20x** | 1.15x (ensemble 1.3x) |"


def test_limit_table_shows_each_methods_time_over_limit_and_a_dash_where_it_has_none(tmp_path: Path):
    rows = [("HalfCheetah-v5", m, "compiled_act_uncertainty_b1", r) for m, r in [("masksembles", 1.234),
                                                                               ("ensemble", 0.75)]]
    csv = tmp_path / "bench.csv"
    pd.DataFrame(rows, columns=["env_id", "method", "measurement", "time_over_limit"]).to_csv(csv, index=False)
    line = next(l for l in readme_results.limit_table(csv).splitlines() if "HalfCheetah, one state, the same" in l)
    assert line.endswith("| - | 1.23x | - | - | 0.75x |")


def test_committed_readme_and_docs_match_what_the_script_pastes(tmp_path: Path, profile: str):
    # the README's headline table and the docs pages' tables must be the committed pipeline outputs, pasted, not typed
    copy_inputs(profile, tmp_path)
    blank_blocks(tmp_path)
    subprocess.run([sys.executable, str(REPO / "scripts/readme_results.py"), profile], cwd=tmp_path, check=True)
    for path in PASTED:
        assert (tmp_path / path).read_text() == (REPO / path).read_text(), (
            f"{path} differs from what `python scripts/readme_results.py` pastes: run it and commit {path}")
    assert not list(tmp_path.rglob("*.tmp")), "a temporary file was left beside a pasted file"


def test_every_paste_holds_the_committed_tables(profile: str):
    # each marker pair of each file holds its tables: a paste that went missing (or landed elsewhere) fails here
    layout = Layout.of(REPO, profile)
    tables = layout.tables
    text = {path: (REPO / path).read_text() for path in PASTED}
    headline = block(text[readme_results.README], readme_results.HEADLINE_START, readme_results.HEADLINE_END)
    assert layout.table(readme_results.HEADLINE_TABLE, "md").read_text().strip() in headline
    results = block(text[readme_results.RESULTS_PAGE], readme_results.START, readme_results.END)
    for name in ("rewards.md", "paper_vs_us_rewards.md", "ood_auroc_perturbed.md", "ood_auroc_noise.md"):
        assert (tables / name).read_text().strip() in results, f"docs/results.md lacks {name}"
    for line in readme_results.reward_lines(layout) + readme_results.auroc_lines(layout):
        assert line in results
    assert block(text[readme_results.BENCH_PAGE], readme_results.BENCH_START, readme_results.BENCH_END) == \
        readme_results.bench_table(REPO / "results/bench/bench.csv")
    assert block(text[readme_results.BENCH_PAGE], readme_results.LIMITS_START, readme_results.LIMITS_END) == \
        readme_results.limit_table(REPO / "results/bench/bench.csv")
    assert block(text[readme_results.DEVIATIONS_PAGE], readme_results.PROBES_START, readme_results.PROBES_END) == \
        readme_results.probe_table(REPO / readme_results.PROBES_CSV)
    # and the README carries only its headline: the other pastes live in docs/
    for start in (readme_results.START, readme_results.BENCH_START, readme_results.PROBES_START):
        assert start not in text[readme_results.README]


def test_a_missing_marker_writes_no_file(tmp_path: Path, profile: str):
    # the script pastes every file in memory first: one page without its markers leaves all files as they were
    copy_inputs(profile, tmp_path)
    page = tmp_path / readme_results.DEVIATIONS_PAGE
    page.write_text(page.read_text().replace(readme_results.PROBES_END, ""))
    blank_blocks(tmp_path)  # every other block stale, so that a write would show
    before = {path: (tmp_path / path).read_text() for path in PASTED}
    run = subprocess.run([sys.executable, str(REPO / "scripts/readme_results.py"), profile], cwd=tmp_path,
                         capture_output=True, text=True)
    assert run.returncode != 0 and "docs/deviations.md has no <!-- probes:start -->" in run.stderr
    assert {path: (tmp_path / path).read_text() for path in PASTED} == before


def test_write_atomic_keeps_the_old_file_when_the_write_fails(tmp_path: Path, monkeypatch):
    target = tmp_path / "README.md"
    target.write_text("old, complete\n")
    target.chmod(0o644)

    def fail(*args):
        raise OSError("disk full")

    monkeypatch.setattr(readme_results.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        readme_results.write_atomic(target, "new " * 1000)
    assert target.read_text() == "old, complete\n"
    assert list(tmp_path.iterdir()) == [target], "the temporary file was left behind"
    monkeypatch.undo()
    readme_results.write_atomic(target, "new\n")
    assert target.read_text() == "new\n" and (target.stat().st_mode & 0o777) == 0o644
    assert list(tmp_path.iterdir()) == [target]
