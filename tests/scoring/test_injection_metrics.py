"""PEDM's per-step metrics and the detection delay, on hand-made episodes."""

import numpy as np
import pandas as pd
import pytest

from paper_lib.scoring.metrics import (delay_threshold, detection_delays, detection_metrics, injection_metrics,
                                       severity_means)

# Two injected episodes (injection at index 2 and 1) and one that ended before its injection (all 0).
SCORES = np.array([0.1, 0.2, 0.9, 0.8, 0.3, 0.7, 0.4, 5.0, 6.0])
LABELS = np.array([0, 0, 1, 1, 0, 1, 1, 0, 0])
EPISODES = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2])


def test_pooled_metrics_drop_episodes_without_injection():
    row = injection_metrics(SCORES, LABELS, EPISODES)
    assert row["n_episodes"] == 2 and row["n_episodes_dropped"] == 1
    # ID steps 0.1, 0.2, 0.3 all lie below the OOD steps 0.4, 0.7, 0.8, 0.9: perfect separation.
    assert row["auroc"] == 1.0 and row["aupr_out"] == 1.0 and row["fpr_at_95_tpr"] == 0.0
    ref = detection_metrics([0.1, 0.2, 0.3], [0.9, 0.8, 0.7, 0.4])
    assert {k: row[k] for k in ref} == ref


def test_cluster_interval_with_rng():
    row = injection_metrics(SCORES, LABELS, EPISODES, rng=np.random.default_rng(0), n_boot=50)
    assert row["ci"] == "cluster" and row["n_id_clusters"] == 2 and row["n_ood_clusters"] == 2


def test_detection_delay_by_hand():
    thr = delay_threshold([0.1, 0.2, 0.3, 0.75], fpr=0.25)  # the 0.75 quantile of the four: 0.4125
    assert thr == pytest.approx(0.4125)
    d = detection_delays(SCORES, LABELS, EPISODES, thr)
    # episode 0: first perturbed step 0.9 is flagged -> delay 0; episode 1: 0.7 flagged at once -> 0;
    assert d["delay"].tolist() == [0.0, 0.0] and d["episode"].tolist() == [0, 1]
    d = detection_delays(SCORES, LABELS, EPISODES, 0.75)
    # with 0.75: episode 0 flags 0.9 at once (0), episode 1 never (0.7, 0.4): NaN
    assert d["delay"].iloc[0] == 0.0 and np.isnan(d["delay"].iloc[1])
    d = detection_delays(np.array([0.5, 0.1, 0.2, 0.6]), np.array([0, 1, 1, 1]), np.zeros(4), 0.3)
    assert d["delay"].tolist() == [2.0] and d["false_alarm"].tolist() == [True]


def test_severity_means():
    rows = pd.DataFrame({"kind": ["a", "b", "a", "b"], "severity": ["minor", "minor", "severe", "severe"],
                         "auroc": [0.5, 0.7, 0.9, 1.0], "aupr_out": [0.1, 0.3, 0.5, 0.7], "fpr_at_95_tpr": [1, 0.8, 0.2, 0]})
    out = severity_means(rows)
    assert out["auroc"].tolist() == pytest.approx([0.6, 0.95])
    assert out["severity"].tolist() == ["minor", "severe"]


def test_bad_input():
    with pytest.raises(ValueError, match="one entry per step"):
        injection_metrics(SCORES, LABELS[:-1], EPISODES)
    with pytest.raises(ValueError, match="NaN"):
        injection_metrics(np.where(LABELS, np.nan, SCORES), LABELS, EPISODES)
    with pytest.raises(ValueError, match="0 \\(before"):
        injection_metrics(SCORES, LABELS * 2, EPISODES)
    with pytest.raises(ValueError, match="before and after"):
        injection_metrics(SCORES, np.zeros(9, int), EPISODES)
    with pytest.raises(ValueError, match="fpr"):
        delay_threshold([0.1], fpr=0)
    with pytest.raises(ValueError, match="lack"):
        severity_means(pd.DataFrame({"kind": ["a"]}))
