"""OOD metrics against hand-computed values (OOD is the positive class)."""

import numpy as np
import pandas as pd
import pytest

from paper_lib.scoring.metrics import bootstrap_auroc_ci, detection_metrics, metrics_table, roc_points

# Hand-computed 3-vs-3 example. Sorted by score (descending): 0.9 O, 0.8 O, 0.4 I, 0.35 I, 0.3 O, 0.1 I.
ID_3 = [0.1, 0.4, 0.35]
OOD_3 = [0.8, 0.3, 0.9]


def test_hand_computed_three_vs_three():
    m = detection_metrics(ID_3, OOD_3)
    # OOD > ID pairs: 0.8 beats 3, 0.3 beats 1 (0.1), 0.9 beats 3 -> 7 of 9.
    assert m["auroc"] == pytest.approx(7 / 9)
    # AP (OOD positive): recall steps of 1/3 at precisions 1, 1, 3/5.
    assert m["aupr_out"] == pytest.approx((1 + 1 + 3 / 5) / 3)
    # AP (ID positive, score negated, ascending s): 0.1 I (1/1), 0.3 O, 0.35 I (2/3), 0.4 I (3/4).
    assert m["aupr_in"] == pytest.approx((1 + 2 / 3 + 3 / 4) / 3)
    # TPR first reaches >= 0.95 at threshold 0.3, where 2 of 3 ID states are above it.
    assert m["fpr_at_95_tpr"] == pytest.approx(2 / 3)
    # Best threshold 0.8: TPR 2/3, FPR 0 -> 0.5 * 1/3.
    assert m["detection_error"] == pytest.approx(1 / 6)
    assert (m["n_id"], m["n_ood"]) == (3, 3)


def test_perfect_separation():
    m = detection_metrics([0.0, 0.1, 0.2], [1.0, 2.0])
    assert m["auroc"] == 1.0
    assert m["aupr_out"] == 1.0 and m["aupr_in"] == 1.0
    assert m["fpr_at_95_tpr"] == 0.0
    assert m["detection_error"] == 0.0


def test_reversed_scores_give_zero_auroc():
    m = detection_metrics([1.0, 2.0], [0.0, 0.1, 0.2])
    assert m["auroc"] == 0.0
    assert m["fpr_at_95_tpr"] == 1.0
    # Best one can do is flag everything or nothing: error 0.5.
    assert m["detection_error"] == pytest.approx(0.5)


def test_identical_distributions_near_chance():
    rng = np.random.default_rng(0)
    m = detection_metrics(rng.normal(size=5000), rng.normal(size=5000))
    assert m["auroc"] == pytest.approx(0.5, abs=0.02)
    assert m["fpr_at_95_tpr"] == pytest.approx(0.95, abs=0.02)


def test_roc_points_match_hand_computed_curve():
    df = roc_points(ID_3, OOD_3, drop_intermediate=False)
    assert list(df.columns) == ["fpr", "tpr", "threshold"]
    np.testing.assert_allclose(df["fpr"], [0, 0, 0, 1 / 3, 2 / 3, 2 / 3, 1])
    np.testing.assert_allclose(df["tpr"], [0, 1 / 3, 2 / 3, 2 / 3, 2 / 3, 1, 1])
    assert np.isinf(df["threshold"].iloc[0])
    assert np.trapezoid(df["tpr"], df["fpr"]) == pytest.approx(7 / 9)


def test_bootstrap_ci_contains_estimate_and_shrinks_with_data():
    rng = np.random.default_rng(1)
    small = (rng.normal(0, 1, 100), rng.normal(1, 1, 100))
    large = (rng.normal(0, 1, 2000), rng.normal(1, 1, 2000))
    lo_s, hi_s = bootstrap_auroc_ci(*small, rng=np.random.default_rng(2), n_boot=500)
    lo_l, hi_l = bootstrap_auroc_ci(*large, rng=np.random.default_rng(2), n_boot=500)
    assert lo_s <= detection_metrics(*small)["auroc"] <= hi_s
    assert lo_l <= detection_metrics(*large)["auroc"] <= hi_l
    # Width scales ~1/sqrt(n): 20x the data should give a clearly narrower interval.
    assert (hi_l - lo_l) < 0.5 * (hi_s - lo_s)


def test_bootstrap_is_seeded_and_matches_sklearn_auroc():
    rng = np.random.default_rng(3)
    id_s, ood_s = np.round(rng.normal(0, 1, 50), 1), np.round(rng.normal(0.5, 1, 40), 1)  # with ties
    a = bootstrap_auroc_ci(id_s, ood_s, np.random.default_rng(7), n_boot=200)
    b = bootstrap_auroc_ci(id_s, ood_s, np.random.default_rng(7), n_boot=200)
    assert a == b
    assert 0.0 <= a[0] <= a[1] <= 1.0
    # With every ID score below every OOD score each replicate has AUROC 1: the CI is exactly (1, 1).
    assert bootstrap_auroc_ci([0, 1, 2], [5, 6], np.random.default_rng(0), n_boot=50) == (1.0, 1.0)


def test_bootstrap_speed_on_4000_scores():
    import time

    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    bootstrap_auroc_ci(rng.normal(size=2000), rng.normal(size=2000), rng, n_boot=1000)
    assert time.perf_counter() - t0 < 10.0  # ~1 s on one core; generous for a loaded machine


def test_metrics_table_rows_and_columns():
    rng = np.random.default_rng(0)
    table = metrics_table({"value": (ID_3, OOD_3), "policy": ([0.0, 0.1], [1.0, 2.0])}, rng, n_boot=100)
    assert isinstance(table, pd.DataFrame)
    assert list(table["measure"]) == ["value", "policy"]
    for col in ["auroc", "aupr_out", "aupr_in", "fpr_at_95_tpr", "detection_error", "n_id", "n_ood",
                "auroc_ci_low", "auroc_ci_high"]:
        assert col in table.columns
    assert table.loc[0, "auroc"] == pytest.approx(7 / 9)
    assert table.loc[1, "auroc_ci_low"] == 1.0


@pytest.mark.parametrize(
    "id_s, ood_s, match",
    [
        ([], [1.0], "id_scores is empty"),
        ([1.0], [], "ood_scores is empty"),
        ([1.0, np.nan], [2.0], "id_scores contains 1 NaN"),
        ([1.0], [2.0, np.nan], "ood_scores contains 1 NaN"),
        (np.ones((2, 2)), [2.0], "id_scores must be a 1-D"),
        ([1.0], np.ones((3, 1)), "ood_scores must be a 1-D"),
    ],
)
def test_bad_scores_raise_naming_the_input(id_s, ood_s, match):
    with pytest.raises(ValueError, match=match):
        detection_metrics(id_s, ood_s)


def test_bad_bootstrap_arguments():
    with pytest.raises(ValueError, match="numpy Generator"):
        bootstrap_auroc_ci([0.0], [1.0], rng=0)
    with pytest.raises(ValueError, match="level"):
        bootstrap_auroc_ci([0.0], [1.0], np.random.default_rng(0), level=95)
    with pytest.raises(ValueError, match="n_boot"):
        bootstrap_auroc_ci([0.0], [1.0], np.random.default_rng(0), n_boot=0)


def test_metrics_table_errors_name_the_measure():
    with pytest.raises(ValueError, match="non-empty dict"):
        metrics_table({}, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"scores\['policy'\]: ood_scores is empty"):
        metrics_table({"value": ([0.0], [1.0]), "policy": ([0.0], [])}, np.random.default_rng(0), n_boot=10)


# ------------------------------------------------------------------------- cluster bootstrap


def _tight_clusters(rng, n_clusters=5, size=200):
    """A few clusters whose states are near-copies: the data holds n_clusters observations, not n_clusters*size."""
    labels = np.repeat(np.arange(n_clusters), size)
    id_s = rng.normal(0.0, 1.0, n_clusters)[labels] + rng.normal(0, 0.02, labels.size)
    ood_s = rng.normal(0.7, 1.0, n_clusters)[labels] + rng.normal(0, 0.02, labels.size)
    return id_s, ood_s, labels


def test_cluster_bootstrap_is_wider_than_the_state_bootstrap_on_tight_clusters():
    from paper_lib.scoring.metrics import cluster_bootstrap_auroc

    id_s, ood_s, labels = _tight_clusters(np.random.default_rng(0))
    state = bootstrap_auroc_ci(id_s, ood_s, np.random.default_rng(1), n_boot=500)
    cluster = cluster_bootstrap_auroc(id_s, ood_s, np.char.add("episode", labels.astype(str)),
                                      np.char.add("config", labels.astype(str)), np.random.default_rng(1), n_boot=500)
    assert cluster.high - cluster.low > 3 * (state[1] - state[0])
    assert cluster.low <= detection_metrics(id_s, ood_s)["auroc"] <= cluster.high
    assert cluster.replicates.shape == (500,)
    # every state its own cluster: the state bootstrap again (same distribution of replicates)
    own = cluster_bootstrap_auroc(id_s, ood_s, None, None, np.random.default_rng(2), n_boot=500)
    assert own.low == pytest.approx(state[0], abs=0.01) and own.high == pytest.approx(state[1], abs=0.01)


def test_weighted_auroc_matches_sklearn_with_sample_weights():
    from sklearn.metrics import roc_auc_score

    from paper_lib.scoring.metrics import _weighted_aurocs

    rng = np.random.default_rng(0)
    id_s, ood_s = np.round(rng.normal(0, 1, 50), 1), np.round(rng.normal(0.5, 1, 40), 1)  # with ties
    w_id, w_ood = rng.integers(0, 4, (6, 50)).astype(float), rng.integers(1, 4, (6, 40)).astype(float)
    w_id[:, 0] += 1
    y = np.r_[np.zeros(50), np.ones(40)]
    expected = [roc_auc_score(y, np.r_[id_s, ood_s], sample_weight=np.r_[a, b]) for a, b in zip(w_id, w_ood)]
    np.testing.assert_allclose(_weighted_aurocs(id_s, ood_s, w_id, w_ood), expected, atol=1e-12)


def test_shared_clusters_are_resampled_together():
    """Noise OOD states made from ID episode e share e's label: one draw moves both sides."""
    from paper_lib.scoring.metrics import cluster_bootstrap_auroc

    labels = np.repeat(["e0", "e1", "e2"], 10)
    id_s = np.repeat([0.0, 1.0, 2.0], 10)
    ood_s = id_s + 0.5  # each OOD state just above its own ID state: AUROC 6/9 on the full sample
    reps = cluster_bootstrap_auroc(id_s, ood_s, labels, labels, np.random.default_rng(0), n_boot=300).replicates
    # a replicate that drew only one episode (3 times) compares that episode with itself: AUROC exactly 1
    assert (reps == 1.0).any() and reps.min() >= 0.5


def test_metrics_over_scoring_seeds_report_their_spread():
    from paper_lib.scoring.metrics import measure_metrics

    rng = np.random.default_rng(0)
    id_s, ood_s = rng.normal(0, 1, (3, 100)), rng.normal(0.5, 1, (3, 80))  # 3 scoring seeds
    row, reps = measure_metrics(id_s, ood_s, np.random.default_rng(1), n_boot=100)
    per_seed = [detection_metrics(i, o)["auroc"] for i, o in zip(id_s, ood_s)]
    assert row["auroc"] == pytest.approx(np.mean(per_seed))
    assert row["auroc_scoring_min"] == min(per_seed) and row["auroc_scoring_max"] == max(per_seed)
    assert row["n_scoring_seeds"] == 3 and row["ci"] == "state" and reps.shape == (100,)
