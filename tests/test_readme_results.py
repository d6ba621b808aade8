"""README numbers are the pipeline's: `scripts/readme_results.py` pastes them, and the README matches its output."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))

import readme_results  # noqa: E402


def test_bench_table_marks_met_targets_and_names_differing_ones(tmp_path: Path):
    rows = [("HalfCheetah-v5", m, "train_steps_per_s", r, t, meets)
            for m, r, t, meets in [("masksembles", 1.1, 1.15, "yes"), ("mc_dropout", 1.3, 1.15, "no"),
                                   ("mc_dropconnect", 2.0, 1.15, "no"), ("ensemble", 1.2, 1.3, "yes")]]
    csv = tmp_path / "bench.csv"
    pd.DataFrame(rows, columns=["env_id", "method", "measurement", "ratio_to_baseline", "target",
                                "meets_target"]).to_csv(csv, index=False)
    line = next(l for l in readme_results.bench_table(csv).splitlines() if l.startswith("| HalfCheetah training"))
    assert line == "| HalfCheetah training | **1.10x** | 1.30x | 2.00x | **1.20x** | 1.15x (ensemble 1.3x) |"


def test_committed_readme_matches_what_the_script_pastes(tmp_path: Path):
    # the README's Results and Benchmarks tables must be the committed pipeline outputs, pasted, not typed
    profile = subprocess.run([sys.executable, "-c", "from paper_lib.config import load_run_config; "
                              "print(load_run_config().profile)"], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout.strip()
    shutil.copy(REPO / "README.md", tmp_path / "README.md")
    for part in (f"results/{profile}/tables", "results/bench"):
        shutil.copytree(REPO / part, tmp_path / part)
    shutil.copy(REPO / f"results/{profile}/runs.md", tmp_path / f"results/{profile}/runs.md")
    (tmp_path / readme_results.PROBES_CSV).parent.mkdir(parents=True)
    shutil.copy(REPO / readme_results.PROBES_CSV, tmp_path / readme_results.PROBES_CSV)
    subprocess.run([sys.executable, str(REPO / "scripts/readme_results.py"), profile], cwd=tmp_path, check=True)
    assert (tmp_path / "README.md").read_text() == (REPO / "README.md").read_text(), (
        "README.md differs from what `python scripts/readme_results.py` pastes: run it and commit README.md")
