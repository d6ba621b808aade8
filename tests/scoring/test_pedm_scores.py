"""PEDM-protocol metrics of a steps table, against values worked out by hand on a tiny case."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from paper_lib.scoring.pedm_scores import protocol_metrics, score_collection


def _steps() -> pd.DataFrame:
    """Held-out ID steps scored 0..19, then one condition: 2 episodes of 4 steps, injected at step 2."""
    held = pd.DataFrame({"condition": -1, "episode": np.repeat([0, 1], 10), "step": np.tile(np.arange(10), 2),
                         "label": 0, "a": np.arange(20.0), "b": np.arange(20.0)})
    # episode 0: the perturbed steps score 30 and 40 (above the threshold 18.05 at once); episode 1: 10 then 25
    test = pd.DataFrame({"condition": 0, "episode": np.repeat([0, 1], 4), "step": np.tile(np.arange(4), 2),
                         "label": [0, 0, 1, 1] * 2, "a": [1.0, 2.0, 30.0, 40.0, 3.0, 4.0, 10.0, 25.0],
                         "b": [1.0, 2.0, 30.0, 40.0, 3.0, 4.0, 10.0, 25.0]})
    return pd.concat([held, test], ignore_index=True)


def test_metrics_delays_and_means_by_hand():
    m = protocol_metrics(_steps(), [("act_noise", "severe")], seed=0, n_boot=50)
    row = m[(m["scorer"] == "a") & (m["kind"] == "act_noise")].iloc[0]
    assert row["auroc"] == 1.0 and row["fpr_at_95_tpr"] == 0.0 and row["aupr_out"] == 1.0
    assert row["threshold"] == pytest.approx(np.quantile(np.arange(20.0), 0.95))  # 18.05
    assert (row["delay_median"], row["delay_mean"], row["detected"], row["false_alarm"]) == (0.5, 0.5, 1.0, 0.0)
    assert (row["n_id"], row["n_ood"], row["n_episodes"], row["n_episodes_dropped"]) == (4, 4, 2, 0)
    mean = m[(m["scorer"] == "a") & (m["kind"] == "mean")].iloc[0]
    assert mean["severity"] == "severe" and mean["auroc"] == 1.0 and pd.isna(mean["n_id"])
    b = m[(m["scorer"] == "b") & (m["kind"] == "act_noise")].iloc[0]
    assert (b["auroc_ci_low"], b["auroc_ci_high"]) == (row["auroc_ci_low"], row["auroc_ci_high"])  # paired resamples


def test_no_held_out_steps_is_one_error():
    steps = _steps()
    with pytest.raises(ValueError, match="held-out ID steps"):
        protocol_metrics(steps[steps["condition"] >= 0], [("act_noise", "severe")], seed=0, n_boot=10)


def test_a_measure_named_as_a_detector_is_refused():
    with pytest.raises(ValueError, match="clash"):
        score_collection({"next_obs": np.zeros((2, 3))}, None, lambda obs: {"pedm": np.zeros(2)})
