"""The recipe-probe summary: several seeds of a variant are kept apart, then averaged."""

from __future__ import annotations

import pandas as pd
import pytest

from paper_lib.experiments.recipe_probes import by_variant


def test_seeds_of_a_variant_are_averaged_and_listed():
    runs = pd.DataFrame({"probe": ["HC/mc_dropout-p0.1", "HC/mc_dropout-p0.1", "HC/baseline"],
                         "seed": [1, 0, 0], "train@100k": [10.0, 30.0, 5.0], "train@300k": [400.0, 1200.0, 2000.0],
                         "eval_deterministic": [1.0, 3.0, 7.0], "eval_sampled": [2.0, 4.0, 8.0]})
    table = by_variant(runs).set_index("probe")
    assert table.loc["HC/mc_dropout-p0.1", "seeds"] == 2 and table.loc["HC/baseline", "seeds"] == 1
    assert table.loc["HC/mc_dropout-p0.1", "train@300k"] == pytest.approx(800.0)
    assert table.loc["HC/mc_dropout-p0.1", "eval_sampled"] == pytest.approx(3.0)
    assert table.loc["HC/mc_dropout-p0.1", "train@300k per seed"] == "1200 / 400"  # in seed order
