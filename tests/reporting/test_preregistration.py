"""The pre-registration (issue 66): its power arithmetic, its committed table, and its entry in params.yaml.

The power of a t-based rule is checked against published values (Cohen's tables / G*Power for the one-sample t
test: d = 1, n = 10 gives 0.8031; d = 0.5 needs n = 34 for 0.80); the committed power table must be what the
seeds registered with it give (`scripts/power_analysis.py --check`), whatever seeds have landed since.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from paper_lib.pipeline.config import read_params
from paper_lib.reporting.power import at_least, clear_probabilities, seeds_needed
from paper_lib.reporting.preregistration import Preregistration, read_power, registered_counts

ROOT = Path(__file__).resolve().parents[2]


def test_the_power_of_a_t_interval_matches_the_published_tables():
    assert sum(clear_probabilities(1.0, 1.0, 10, 0.0)) == pytest.approx(0.8031, abs=1e-4)
    assert seeds_needed(lambda n: sum(clear_probabilities(0.5, 1.0, n, 0.0))) == 34
    # a simultaneous level asks for more seeds than a single 95% interval
    single = seeds_needed(lambda n: clear_probabilities(1.0, 1.0, n, 0.0)[0])
    family = seeds_needed(lambda n: clear_probabilities(1.0, 1.0, n, 0.0, level_above=1 - 0.05 / 12)[0])
    assert family > single
    # far tails that scipy's nct underflows to NaN read 0 (far side) and 1 (near side)
    above, below = clear_probabilities(0.5, 0.001, 5, 0.0)
    assert above == 1.0 and below == 0.0


def test_the_poisson_binomial_tail_and_the_search_bound():
    assert at_least([0.5, 0.5], 1) == pytest.approx(0.75) and at_least([0.2, 0.3, 0.4], 3) == pytest.approx(0.024)
    assert seeds_needed(lambda n: 0.0, max_seeds=10) is None
    with pytest.raises(ValueError, match="power must lie strictly between 0 and 1"):
        seeds_needed(lambda n: 1.0, power=1.0)


def test_the_committed_power_table_is_what_the_registered_seeds_give():
    """Recomputed from seeds 0-2 of the committed per-run files: the same bytes, and the same docs summary."""
    done = subprocess.run([sys.executable, "scripts/power_analysis.py", "--check"], cwd=ROOT, capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stderr
    table = read_power(ROOT / Preregistration.from_params(read_params(ROOT / "params.yaml")).power_file)
    counts = registered_counts(table)
    assert counts[("masksembles_reward", "HalfCheetah-v5")] == np.inf  # spread of ~1700 against a margin of ~440
    assert ("masksembles_reward", "SeaquestNoFrameskip-v4") not in counts  # one seed: no spread to size from


def test_a_missing_registration_or_power_table_is_one_clear_error(tmp_path):
    params = read_params(ROOT / "params.yaml")
    with pytest.raises(ValueError, match="no `preregistration` entry"):
        Preregistration.from_params({k: v for k, v in params.items() if k != "preregistration"})
    with pytest.raises(ValueError, match="unknown key"):
        Preregistration.from_params({**params, "preregistration": {**params["preregistration"], "margin": 0.2}})
    entry = params["preregistration"]
    without_versus = {k: v for k, v in entry["pedm"].items() if k != "versus"}
    with pytest.raises(ValueError, match=r"preregistration\.pedm.*versus"):
        Preregistration.from_params({**params, "preregistration": {**entry, "pedm": without_versus}})
    assert Preregistration.from_params(params).pedm["versus"] == "pedm"
    with pytest.raises(ValueError, match="written once by scripts/power_analysis.py"):
        read_power(tmp_path / "power.csv")


def test_the_plan_is_the_papers_atari_count_and_five_mujoco_seeds():
    prereg = Preregistration.from_params(read_params(ROOT / "params.yaml"))
    assert prereg.planned("SeaquestNoFrameskip-v4") == [0, 1, 2]
    assert prereg.planned("Ant-v5") == [0, 1, 2, 3, 4]
    # the power analysis read what was committed at registration: MuJoCo seeds 0-2, Atari seed 0 only, so a later
    # Atari seed (1 landed on 2026-12-05) never moves the registered table (the --check test below)
    assert prereg.power_seeds == {"MuJoCo": [0, 1, 2], "Atari": [0]}
    rows = pd.DataFrame({"env": ["Ant-v5", "Ant-v5", "SeaquestNoFrameskip-v4", "SeaquestNoFrameskip-v4"],
                         "seed": [2, 3, 0, 1]})
    assert prereg.power_rows(rows).values.tolist() == [["Ant-v5", 2], ["SeaquestNoFrameskip-v4", 0]]
