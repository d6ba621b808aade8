"""PEDM on Table 2's states: a fitted dynamics detector scores one simulated transition from each evaluated state.

The states are the very ones the `score` stage evaluates (`ood_scores.evaluation_parts` with a fresh rng of the run's
seed: the held-apart ID episodes, the perturbed set, the noise states), each made a transition by
`ood.transitions.transitions_from_states` under its own physics; the AUROCs and their cluster-bootstrap intervals come
from the same resamples (`sequence_scores.metrics_on_parts`), so PEDM's cells pair with every other measure's of the
run. A noise state is an ID state plus noise, stepped under the unmodified physics: PEDM meets it as a state its
model has not seen, as every other detector does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from paper_lib.measures.dynamics import PEDMDetector
from paper_lib.ood.datasets import StateDataset, check_labels
from paper_lib.ood.transitions import EXACT_ENVS, transitions_from_states
from paper_lib.scoring.ood_scores import evaluation_parts
from paper_lib.scoring.sequence_scores import metrics_on_parts

#: The measure name PEDM's rows carry in Table 2 and in the stage's files.
PEDM_MEASURE = "pedm"


@dataclass
class TransitionScores:
    scores: dict[str, np.ndarray]  # part ("id", "perturbed", "noise") -> PEDM's score per state
    metrics: pd.DataFrame  # one row per OOD set, the `score` stage's metric columns (METRIC_ORDER)
    replicates: pd.DataFrame  # cluster-bootstrap AUROC replicates per OOD set


def score_pedm_on_dataset(detector: PEDMDetector, dataset: StateDataset, seed: int,
                          predict: Callable[[np.ndarray], np.ndarray],
                          policy_obs: Callable[[np.ndarray], np.ndarray] | None, n_bootstrap: int,
                          noise_magnitude: float = 2.0, level: float = 0.95) -> TransitionScores:
    """PEDM's AUROC on the run's perturbed and noise sets against its held-apart ID states.

    ``seed`` is the run's seed (the `score` stage's split, noise and resamples); ``predict`` and ``policy_obs`` are
    the run's agent (`transitions_from_states`); ``noise_magnitude`` must be the `score` stage's.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r}: give the run's seed (an int >= 0), the one its `score` stage used.")
    env_id = dataset.metadata.get("env_id")
    if env_id not in EXACT_ENVS:
        raise ValueError(f"PEDM scores Table 2's states of {EXACT_ENVS}, whose observations determine the simulator "
                         f"state; got a dataset of {env_id!r} (docs/deviations.md)")
    check_labels(dataset)
    rng = np.random.default_rng(seed)
    _, parts = evaluation_parts(replace(dataset, policy_obs=None), rng, noise_magnitude)  # raw states, as `sequence_score`
    scores = {}
    for i, (name, data) in enumerate(parts.items()):
        moves = transitions_from_states(predict, data, policy_obs, torch_seed=int(
            np.random.SeedSequence([int(seed), 69, i]).generate_state(1)[0]))
        scores[name] = detector.score(data.states, moves.actions, moves.next_obs)
    metrics, replicates = metrics_on_parts({k: {PEDM_MEASURE: v} for k, v in scores.items()}, (PEDM_MEASURE,), parts,
                                           rng, n_bootstrap, level)
    return TransitionScores(scores, metrics, replicates)
