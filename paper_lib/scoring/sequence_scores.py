"""The two sequence detectors (DEEDEE-style episode mean, DEXTER-style window forest) on a run's main ID/OOD dataset.

They read only observation sequences, so they score Table 2's states without new collection (PEDM needs a transition
from each state: `scoring.transition_scores`, in the `pedm` stage). The states are the
very ones the `score` stage evaluates: `ood_scores.evaluation_parts` with a fresh rng of the run's seed gives the same
ID fit episodes, held-apart ID episodes and noise states, and `ood_scores.resample_seeds` then the same cluster
resamples, so these AUROCs and their intervals pair with every other measure's of the run.

- Fit: the ID fit half's episodes, whole (`split_fit_eval` puts every episode on one side), as their kept states in
  step order; no state of an evaluated episode is seen in fitting.
- Score: each evaluated state from its episode's kept states up to it (the collection dropped each episode's first
  `skip_first` steps, so a sequence starts there), the window forest causal (`WindowForestDetector(causal=True)`).
  A noise state is its ID episode's state plus noise, so a noise episode is an ID episode with noise at every step.
- Observations: the raw env states (as in PEDM's protocol stage), not the normalizer's view; both detectors
  standardize or are scale-free per dimension.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from paper_lib.measures.sequences import EpisodeMeanDetector, WindowForestDetector
from paper_lib.ood.datasets import StateDataset, check_labels
from paper_lib.scoring.metrics import measure_metrics
from paper_lib.scoring.ood_scores import METRIC_ORDER, bootstrap_clusters, evaluation_parts, resample_seeds

SEQUENCE_DETECTORS = ("episode_mean", "window_forest")


@dataclass
class SequenceScores:
    scores: dict[str, dict[str, np.ndarray]]  # part ("id", "perturbed", "noise") -> detector -> one score per state
    metrics: pd.DataFrame  # one row per (ood_set, detector), the `score` stage's metric columns (METRIC_ORDER)
    replicates: pd.DataFrame  # cluster-bootstrap AUROC replicates per (ood_set, measure)


def episode_rows(data: StateDataset) -> list[np.ndarray]:
    """Each episode's row indices in `data`, in step order (episodes in order of first appearance).

    A state's episode is its `episode` id within the part; its steps must be distinct (two episodes under one id, or
    a state twice, would make one sequence of two), else one error naming the episode.
    """
    rows = []
    for e in dict.fromkeys(data.episode.tolist()):
        r = np.flatnonzero(data.episode == e)
        r = r[np.argsort(data.step[r], kind="stable")]
        if np.any(np.diff(data.step[r]) <= 0):
            raise ValueError(f"episode {e} holds step(s) twice ({data.step[r].tolist()[:12]}...): the dataset's episode "
                             "ids do not name single episodes; collect it again (`make recollect`)")
        rows.append(r)
    return rows


def fit_sequence_detectors(id_fit: StateDataset, seed: int) -> dict[str, EpisodeMeanDetector | WindowForestDetector]:
    """Both detectors fit on the ID fit episodes' raw states (whole episodes)."""
    episodes = [id_fit.states[r] for r in episode_rows(id_fit)]
    return {"episode_mean": EpisodeMeanDetector().fit(episodes),
            "window_forest": WindowForestDetector(seed=seed, causal=True).fit(episodes)}


def score_part(detectors: dict[str, EpisodeMeanDetector | WindowForestDetector],
               data: StateDataset) -> dict[str, np.ndarray]:
    """Every detector's score of each state of `data` (in its row order), from its episode's states up to it."""
    rows = episode_rows(data)
    episodes = [data.states[r] for r in rows]
    out = {}
    for name, detector in detectors.items():
        scores = np.empty(len(data))
        for r, s in zip(rows, detector.score(episodes)):
            scores[r] = s
        out[name] = scores
    return out


def score_sequences(dataset: StateDataset, seed: int, n_bootstrap: int, noise_magnitude: float = 2.0,
                    level: float = 0.95) -> SequenceScores:
    """Both sequence detectors on the run's perturbed and noise OOD sets against its held-apart ID states.

    ``seed`` is the run's seed, as the `score` stage takes it (`score_run`); ``noise_magnitude`` must be the one
    that stage used (its default), or the noise states differ from Table 2's.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r}: give the run's seed (an int >= 0), the one its `score` stage used.")
    check_labels(dataset)
    if dataset.states.ndim != 2:
        raise ValueError(f"the sequence detectors read vector observations, got states of shape "
                         f"{dataset.states.shape[1:]} (pixels): score a MuJoCo run's dataset.")
    rng = np.random.default_rng(seed)
    # The normalizer's view (policy_obs) is not read here; without it the noise needs no normalizer, and the noise
    # drawn from rng, on the raw states, is the same.
    id_fit, parts = evaluation_parts(replace(dataset, policy_obs=None), rng, noise_magnitude)
    detectors = fit_sequence_detectors(id_fit, int(seed))
    scores = {name: score_part(detectors, data) for name, data in parts.items()}
    metrics, replicates = metrics_on_parts(scores, SEQUENCE_DETECTORS, parts, rng, n_bootstrap, level)
    return SequenceScores(scores, metrics, replicates)


def metrics_on_parts(scores: dict[str, dict[str, np.ndarray]], detectors: tuple[str, ...],
                     parts: dict[str, StateDataset], rng: np.random.Generator, n_bootstrap: int,
                     level: float = 0.95) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(metrics, AUROC replicates) of `detectors` on both OOD sets, as the `score` stage computes its own.

    ``scores`` is part -> detector -> one score per state of ``parts[part]``; ``rng`` is the run's seed's generator
    right after `evaluation_parts`, so the cluster resamples are the `score` stage's (`resample_seeds`).
    """
    rows, replicates = [], []
    for ood_set, resample_seed in resample_seeds(rng).items():
        id_clusters, ood_clusters = bootstrap_clusters(parts, ood_set)
        for name in detectors:
            row, reps = measure_metrics(scores["id"][name], scores[ood_set][name], np.random.default_rng(resample_seed),
                                        n_boot=n_bootstrap, level=level, id_clusters=id_clusters,
                                        ood_clusters=ood_clusters)
            rows.append({"ood_set": ood_set, "measure": name, **row})
            replicates.append(pd.DataFrame({"ood_set": ood_set, "measure": name, "replicate": np.arange(reps.size),
                                            "auroc": reps}))
    return pd.DataFrame(rows)[list(METRIC_ORDER)], pd.concat(replicates, ignore_index=True)
