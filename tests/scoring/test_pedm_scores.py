"""PEDM-protocol metrics of a steps table, against values worked out by hand on a tiny case."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from paper_lib.scoring.pedm_scores import CLOCK, protocol_metrics, score_collection, step_metrics


def _steps() -> pd.DataFrame:
    """Held-out ID steps scored 0..19, then one condition: 2 episodes of 4 steps, injected at step 2."""
    held = pd.DataFrame({"condition": -1, "episode": np.repeat([0, 1], 10), "step": np.tile(np.arange(10), 2),
                         "label": 0, "a": np.arange(20.0), "b": np.arange(20.0)})
    # episode 0: the perturbed steps score 30 and 40 (above the threshold 19 at once); episode 1: 10 then 25
    test = pd.DataFrame({"condition": 0, "episode": np.repeat([0, 1], 4), "step": np.tile(np.arange(4), 2),
                         "label": [0, 0, 1, 1] * 2, "a": [1.0, 2.0, 30.0, 40.0, 3.0, 4.0, 10.0, 25.0],
                         "b": [1.0, 2.0, 30.0, 40.0, 3.0, 4.0, 10.0, 25.0]})
    return pd.concat([held, test], ignore_index=True)


def test_metrics_and_means_by_hand():
    m = protocol_metrics(_steps(), [("act_noise", "severe")], seed=0, n_boot=50)
    row = m[(m["scorer"] == "a") & (m["kind"] == "act_noise")].iloc[0]
    assert row["auroc"] == 1.0 and row["fpr_at_95_tpr"] == 0.0 and row["aupr_out"] == 1.0
    assert "delay_median" not in m.columns  # computed from the stored steps where they are read (`step_metrics`)
    assert (row["n_id"], row["n_ood"], row["n_episodes"], row["n_episodes_dropped"]) == (4, 4, 2, 0)
    mean = m[(m["scorer"] == "a") & (m["kind"] == "mean")].iloc[0]
    assert mean["severity"] == "severe" and mean["auroc"] == 1.0 and pd.isna(mean["n_id"])
    b = m[(m["scorer"] == "b") & (m["kind"] == "act_noise")].iloc[0]
    assert (b["auroc_ci_low"], b["auroc_ci_high"]) == (row["auroc_ci_low"], row["auroc_ci_high"])  # paired resamples


def test_delays_time_matched_auroc_and_the_clock_by_hand():
    m = step_metrics(_steps(), [("act_noise", "severe")]).set_index(["scorer", "kind"])
    row = m.loc[("a", "act_noise")]
    # held-out episode maxima 9 and 19: alpha 1/3, rank ceil(3 * 2/3) = 2, so 19; an ID episode alarms w.p. <= 1/3
    assert (row["threshold"], row["false_alarm_bound"]) == (19.0, pytest.approx(1 / 3))
    # episode 0 flags 30 at the injection (0 steps), episode 1 flags 25 one step after it (10 is below 19)
    assert (row["delay_median"], row["delay_mean"], row["detected"], row["false_alarm"]) == (0.5, 0.5, 1.0, 0.0)
    # against the held-out steps at the same index (step 2: 2, 12; step 3: 3, 13): 30, 40 and 25 beat both, 10 one
    assert row["auroc_time_matched"] == 7 / 8
    clock = m.loc[(CLOCK, "act_noise")]
    # the step index alone: ID steps 0, 1 below perturbed steps 2, 3 pooled; time-matched every pair ties
    assert (clock["auroc"], clock["aupr_out"], clock["fpr_at_95_tpr"], clock["auroc_time_matched"]) == (1, 1, 0, 0.5)
    assert np.isnan(clock["delay_median"]) and np.isnan(clock["threshold"])
    assert m.loc[(CLOCK, "mean"), "auroc"] == 1.0 and m.loc[("a", "mean"), "auroc_time_matched"] == 7 / 8


def test_no_held_out_steps_is_one_error():
    steps = _steps()
    with pytest.raises(ValueError, match="held-out ID steps"):
        step_metrics(steps[steps["condition"] >= 0], [("act_noise", "severe")])


def test_a_measure_named_as_a_detector_is_refused():
    with pytest.raises(ValueError, match="clash"):
        score_collection({"next_obs": np.zeros((2, 3))}, None, lambda obs: {"pedm": np.zeros(2)})
