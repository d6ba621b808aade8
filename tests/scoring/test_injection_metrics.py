"""PEDM's per-step metrics, the detection delay and the time-matched AUROC, on hand-made episodes."""

import numpy as np
import pandas as pd
import pytest

from paper_lib.scoring.metrics import (detection_delays, detection_metrics, episode_threshold, injection_metrics,
                                       severity_means, time_matched_auroc)

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


def test_episode_threshold_by_hand():
    """Three held-out episodes with maxima 0.5, 0.9, 0.4: split conformal on the maxima (rank ceil(4 (1 - alpha)))."""
    scores, episodes = [0.1, 0.5, 0.2, 0.3, 0.9, 0.4], [0, 0, 0, 1, 1, 2]
    assert episode_threshold(scores, episodes) == (0.9, 0.25)  # alpha 1/4, the least 3 allow: the largest maximum
    assert episode_threshold(scores, episodes, alpha=0.5) == (0.5, 0.5)  # rank 2 of 3; bound (3 + 1 - 2) / 4
    with pytest.raises(ValueError, match="at least 9 held-out ID episodes"):
        episode_threshold(scores, episodes, alpha=0.1)


def test_a_chance_scorer_alarms_in_nearly_every_episode_per_step_but_rarely_per_episode():
    """I.i.d. scores (a scorer at chance) over episodes of 500 steps, injected at step 100-399, 5 held-out episodes:
    the old per-step rule (the 95% quantile of held-out steps) flags over 99% of the episodes before their injection;
    the episode rule under 15% (its bound 1/6 holds for whole episodes; the part before an injection is shorter),
    averaged over 100 held-out sets (one set's rate is random)."""
    rng = np.random.default_rng(0)
    per_step, per_episode = [], []
    for _ in range(100):
        held = rng.normal(size=(5, 500))
        before = rng.normal(size=(20, 500))
        before[np.arange(500)[None] >= rng.integers(100, 400, size=20)[:, None]] = -np.inf  # from the injection on
        peak = before.max(axis=1)
        per_step.append((peak > np.quantile(held, 0.95)).mean())
        threshold, bound = episode_threshold(held.ravel(), np.repeat(np.arange(5), 500))
        per_episode.append((peak > threshold).mean())
    assert bound == pytest.approx(1 / 6)
    assert np.mean(per_step) > 0.99 and np.mean(per_episode) < 0.15


def test_time_matched_auroc_by_hand():
    """Held-out ID: two episodes of steps 0-2; each perturbed step meets the ID steps at its own step index."""
    id_scores, id_steps = [1.0, 2.0, 3.0, 3.0, 2.0, 1.0], [0, 1, 2, 0, 1, 2]
    steps, labels = np.array([0, 1, 2, 3]), np.array([0, 1, 1, 1])
    # step 1 scores 2 against {2, 2}: two ties (1); step 2 scores 0 against {3, 1}: 0; step 3 has no ID step: left out
    assert time_matched_auroc([9.0, 2.0, 0.0, 5.0], labels, steps, id_scores, id_steps) == 1 / 4
    assert time_matched_auroc([0.0, 4.0, 4.0, 0.0], labels, steps, id_scores, id_steps) == 1.0
    # the step index as the score (the clock): every pair a tie, 0.5; PEDM's pooled AUROC gives it 1 (step 0 is ID)
    assert time_matched_auroc(steps, labels, steps, id_steps, id_steps) == 0.5
    assert injection_metrics(steps, labels, np.zeros(4))["auroc"] == 1.0
    assert np.isnan(time_matched_auroc([1.0, 1.0], [0, 1], [0, 7], id_scores, id_steps))


def test_detection_delay_by_hand():
    thr = 0.4125
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
    with pytest.raises(ValueError, match="one entry per step"):
        episode_threshold([0.1, 0.2], [0])
    with pytest.raises(ValueError, match="one entry per step"):
        time_matched_auroc([0.1, 0.2], [0, 1], [0], [0.1], [0])
    with pytest.raises(ValueError, match="lack"):
        severity_means(pd.DataFrame({"kind": ["a"]}))
