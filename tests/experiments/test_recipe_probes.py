"""The recipe-probe summary: several seeds of a variant are kept apart, then averaged; summarized runs are kept."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from paper_lib.experiments.recipe_probes import by_variant, summarize


def test_seeds_of_a_variant_are_averaged_and_listed():
    runs = pd.DataFrame({"probe": ["HC/mc_dropout-p0.1", "HC/mc_dropout-p0.1", "HC/baseline"],
                         "seed": [1, 0, 0], "train@100k": [10.0, 30.0, 5.0], "train@300k": [400.0, 1200.0, 2000.0],
                         "eval_deterministic": [1.0, 3.0, 7.0], "eval_sampled": [2.0, 4.0, 8.0]})
    table = by_variant(runs).set_index("probe")
    assert table.loc["HC/mc_dropout-p0.1", "seeds"] == 2 and table.loc["HC/baseline", "seeds"] == 1
    assert table.loc["HC/mc_dropout-p0.1", "train@300k"] == pytest.approx(800.0)
    assert table.loc["HC/mc_dropout-p0.1", "eval_sampled"] == pytest.approx(3.0)
    assert table.loc["HC/mc_dropout-p0.1", "train@300k per seed"] == "1200 / 400"  # in seed order


def test_summarized_runs_are_kept_not_evaluated_again(tmp_path):
    """A run already in the summary (same probe, seed, steps) keeps its row without loading or stepping
    anything, and a row whose folder has gone stays; the run folder here holds no model to evaluate."""
    run = tmp_path / "Walker2d-v5" / "baseline-zoo" / "seed1"
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"seed": 1, "method": "baseline"}))
    pd.DataFrame({"timesteps": [2048, 4096], "reward": [1.0, 2.0]}).to_csv(run / "training_curve.csv", index=False)
    columns = {"method": "baseline", "train@100k": 5.0, "eval_deterministic": 7.0, "eval_sampled": 6.0,
               "dropout_p": 0.1, "masksembles_scale": 2.0, "policy": "SB3 defaults", "normalize_obs": False,
               "normalize_reward": False, "wall_minutes": 1.0}
    known = pd.DataFrame([{"probe": "Walker2d-v5/baseline-zoo", "seed": 1, "steps": 4096, **columns},
                          {"probe": "Swimmer-v5/previous-recipe", "seed": 0, "steps": 1000, **columns}])
    table = summarize(tmp_path, {}, known=known)
    assert list(table["probe"]) == ["Swimmer-v5/previous-recipe", "Walker2d-v5/baseline-zoo"]
    assert table["eval_deterministic"].tolist() == [7.0, 7.0]
    # the run has grown since: it is evaluated again (and here, with no model, that fails loudly)
    known.loc[0, "steps"] = 2048
    with pytest.raises(FileNotFoundError, match="model.zip is missing"):
        summarize(tmp_path, {}, known=known)
