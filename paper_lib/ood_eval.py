"""Scoring one run's ID/OOD dataset with every detector and turning the scores into metrics.

Every detector is evaluated on the same states: the ID states held apart from the detector
fitting half, and all OOD states. The member-free detectors (Mahalanobis, kNN) are fitted
on the other ID half, so they never score a state they were fitted on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from paper_lib.checkpoints import Checkpoint
from paper_lib.detectors import KNNDetector, MahalanobisDetector, split_fit_eval
from paper_lib.metrics import metrics_table, roc_points
from paper_lib.ood.collect import noise_ood_states, score_dataset
from paper_lib.ood.datasets import StateDataset
from paper_lib.uncertainty import policy_features



@dataclass
class RunScores:
    scores: pd.DataFrame  # one row per evaluated state: label, ood_set, source, episode, step, one column per detector
    metrics: pd.DataFrame  # one row per (ood_set, detector): AUROC, AUPR-in/out, FPR@95, detection error, CI
    roc: pd.DataFrame  # ROC points per (ood_set, detector)


def score_run(checkpoint: Checkpoint, dataset: StateDataset, rng: np.random.Generator, n_bootstrap: int,
              noise_magnitude: float = 2.0) -> RunScores:
    """All measures and detectors on the physics (or game-state) OOD set and on the noise OOD set.

    The held-apart ID states are scored once and serve as the ID side of both OOD sets.
    """
    id_data, ood_data = dataset.id_only(), dataset.ood_only()
    fit_idx, eval_idx = split_fit_eval(len(id_data), rng)
    id_fit, id_eval = id_data.subset(_mask(len(id_data), fit_idx)), id_data.subset(_mask(len(id_data), eval_idx))
    noise = noise_ood_states(id_eval, rng, magnitude=noise_magnitude)
    detectors = _fit_detectors(checkpoint, id_fit)
    id_scored = _score(checkpoint, id_eval, detectors)
    frames, metric_rows, rocs = [], [], []
    for ood_set, ood in (("perturbed", ood_data), ("noise", noise)):
        scored = pd.concat([id_scored, _score(checkpoint, ood, detectors)], ignore_index=True).assign(ood_set=ood_set)
        frames.append(scored)
        columns = [c for c in scored.columns if c not in _META]
        pairs = {c: (scored.loc[scored.label == 0, c].to_numpy(), scored.loc[scored.label == 1, c].to_numpy())
                 for c in columns}
        metric_rows.append(metrics_table(pairs, rng, n_boot=n_bootstrap).assign(ood_set=ood_set))
        for c, (i, o) in pairs.items():
            rocs.append(roc_points(i, o).assign(measure=c, ood_set=ood_set))
    return RunScores(pd.concat(frames, ignore_index=True), pd.concat(metric_rows, ignore_index=True),
                     pd.concat(rocs, ignore_index=True))


_META = ("label", "source", "episode", "step", "config_index", "ood_set")


def _mask(n: int, idx: np.ndarray) -> np.ndarray:
    mask = np.zeros(n, dtype=bool)
    mask[idx] = True
    return mask


def _policy_obs(data: StateDataset) -> np.ndarray:
    return data.policy_obs if data.policy_obs is not None else data.states


def _detector_inputs(checkpoint: Checkpoint, data: StateDataset) -> dict[str, np.ndarray]:
    """What each member-free detector reads: observations (as the policy sees them) or policy features."""
    obs = _policy_obs(data)
    feats = policy_features(checkpoint.model.policy, obs)
    return {"knn_obs": obs.reshape(len(obs), -1).astype(np.float32), "mahalanobis_obs": obs,
            "mahalanobis_features": feats, "knn_features": feats}


def _fit_detectors(checkpoint: Checkpoint, id_fit: StateDataset) -> dict:
    inputs = _detector_inputs(checkpoint, id_fit)
    detectors = {"knn_obs": KNNDetector(), "mahalanobis_features": MahalanobisDetector(),
                 "knn_features": KNNDetector()}
    if inputs["mahalanobis_obs"].ndim == 2:  # on raw pixels it would need a (84*84*4)^2 covariance
        detectors["mahalanobis_obs"] = MahalanobisDetector()
    return {name: det.fit(inputs[name]) for name, det in detectors.items()}


def _score(checkpoint: Checkpoint, data: StateDataset, detectors: dict) -> pd.DataFrame:
    scored = score_dataset(checkpoint.model, data)
    inputs = _detector_inputs(checkpoint, data)
    for name, det in detectors.items():
        scored[name] = det.score(inputs[name])
    return scored
