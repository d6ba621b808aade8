"""The sequence detectors on a main ID/OOD dataset (`scoring.sequence_scores`): a tiny case computed by hand."""

import json
import math

import numpy as np
import pytest

from paper_lib.measures.sequences import WindowForestDetector
from paper_lib.ood.datasets import StateDataset
from paper_lib.scoring.ood_scores import METRIC_ORDER
from paper_lib.scoring.sequence_scores import SEQUENCE_DETECTORS, episode_rows, score_sequences

#: ID episode e holds 3 steps (10, 11, 12: the collection's kept steps) of the constant value ID_VALUES[e].
ID_VALUES = (0.0, 5.0, 2.0, 1.0)


def tiny_dataset() -> StateDataset:
    """4 ID episodes and 2 OOD episodes (one of a single step), 1-D states, the OOD rows out of step order."""
    states, labels, source, config, episode, step = [], [], [], [], [], []
    for e, value in enumerate(ID_VALUES):
        for t in (10, 11, 12):
            states.append([value]), labels.append(0), source.append("id"), config.append(-1)
            episode.append(e), step.append(t)
    for e, value, steps in ((0, 3.0, (12, 10, 11)), (1, -1.0, (10,))):
        for t in steps:
            states.append([value + 0.1 * t]), labels.append(1), source.append("gravity"), config.append(e)
            episode.append(e), step.append(t)
    configs = [json.dumps({"gravity": g}) for g in (0.5, 2.0)]
    return StateDataset(states=np.array(states), labels=labels, source=source, config_index=config, episode=episode,
                        step=step, configs=configs)


def test_fit_on_the_fit_episodes_only_and_each_state_from_its_episode_by_hand():
    # Seed 0: split_fit_eval puts episodes rng.permutation(4)[:2] = [2, 0] in the fit half (whole episodes), so the
    # detectors see values 0 and 2 only: mean 1, std 1; standardized running means -1 and +1 at every step, squared
    # distance 4 between them, so sigma^2 = 4 / 2 = 2. The evaluated ID episodes are 1 (value 5) and 3 (value 1).
    result = score_sequences(tiny_dataset(), seed=0, n_bootstrap=20)
    id_scores = result.scores["id"]["episode_mean"]
    assert id_scores.shape == (6,)  # episodes 1 and 3, three steps each: no fit state is evaluated
    # episode 3 standardizes to 0: squared distance 1 to both summaries -> log 2 - log(2 e^(-1/4)) = 0.25
    np.testing.assert_allclose(id_scores[3:], 0.25)
    # episode 1 standardizes to 4: squared distances 25 and 9 -> log 2 - log(e^(-25/4) + e^(-9/4))
    np.testing.assert_allclose(id_scores[:3], math.log(2) - math.log(math.exp(-25 / 4) + math.exp(-9 / 4)))

    fit = [np.full((3, 1), ID_VALUES[e]) for e in (0, 2)]  # the window forest too: fit on those two episodes alone
    forest = WindowForestDetector(seed=0, causal=True).fit(fit)
    np.testing.assert_array_equal(result.scores["id"]["window_forest"],
                                  np.concatenate(forest.score([np.full((3, 1), ID_VALUES[e]) for e in (1, 3)])))

    metrics = result.metrics
    assert list(metrics.columns) == list(METRIC_ORDER)
    assert list(zip(metrics.ood_set, metrics.measure)) == [(o, d) for o in ("perturbed", "noise")
                                                           for d in SEQUENCE_DETECTORS]
    perturbed = metrics[metrics.ood_set == "perturbed"].iloc[0]
    assert (perturbed.n_id, perturbed.n_id_clusters, perturbed.n_ood, perturbed.n_ood_clusters) == (6, 2, 4, 2)
    assert (metrics.ci == "cluster").all() and metrics.auroc.between(0, 1).all()


def test_an_episode_is_scored_in_step_order_whatever_the_row_order():
    data = tiny_dataset().ood_only()
    rows = episode_rows(data)
    assert [data.step[r].tolist() for r in rows] == [[10, 11, 12], [10]]
    twice = StateDataset(states=np.zeros((2, 1)), labels=[0, 0], source=["id", "id"], config_index=[-1, -1],
                         episode=[4, 4], step=[10, 10])
    with pytest.raises(ValueError, match="episode 4 holds step"):
        episode_rows(twice)


def test_pixels_are_refused():
    frames = StateDataset(states=np.zeros((2, 2, 2), dtype=np.uint8), labels=[0, 1], source=["id", "noise"],
                          config_index=[-1, -1], episode=[0, 0], step=[0, 1])
    with pytest.raises(ValueError, match="vector observations"):
        score_sequences(frames, seed=0, n_bootstrap=10)
