"""Feature-space OOD detectors that need no ensemble members.

They score a state by how far it lies from ID states in observation space, which
gives a reference point for the ensemble-based uncertainty measures: if a plain
distance in state space already separates ID from OOD, the benchmark is easy.
Fit them on ID states held apart from the ID states used for evaluation
(``split_fit_eval``); otherwise the evaluation ID states sit at distance ~0 from
themselves and the AUROC is inflated.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from sklearn.covariance import EmpiricalCovariance, LedoitWolf
from sklearn.neighbors import NearestNeighbors
from sklearn.preprocessing import StandardScaler


def _as_2d(X: np.ndarray, name: str) -> np.ndarray:
    """Return states as a finite (n_samples, n_features) float array; image-shaped states are flattened."""
    arr = np.asarray(X, dtype=float)
    if arr.ndim < 2:
        raise ValueError(
            f"{name} must have one row per state (shape (n, ...)), got shape {arr.shape}; "
            "for a single feature use X.reshape(-1, 1), for a single state X[None]."
        )
    if arr.shape[0] == 0:
        raise ValueError(f"{name} holds no states (shape {arr.shape}); pass at least one state.")
    arr = arr.reshape(arr.shape[0], -1)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN/inf values; drop or fix those states first.")
    return arr


class _Detector:
    """Shared fit/score plumbing: standardize on the fit data, check dimensions."""

    min_fit_samples_reason = ""

    def __init__(self) -> None:
        self.scaler_: StandardScaler | None = None

    def _min_fit_samples(self, n_features: int) -> int:
        raise NotImplementedError

    def _fit_standardized(self, Z: np.ndarray) -> None:
        raise NotImplementedError

    def _score_standardized(self, Z: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def fit(self, X: np.ndarray) -> "_Detector":
        """Fit on ID states X (n, ...). Features are standardized so no unit dominates the distance."""
        Xf = _as_2d(X, "X (fit states)")
        need = self._min_fit_samples(Xf.shape[1])
        if Xf.shape[0] < need:
            raise ValueError(
                f"{type(self).__name__}.fit got {Xf.shape[0]} states but needs at least {need} "
                f"({self.min_fit_samples_reason}); pass more ID states."
            )
        self.scaler_ = StandardScaler().fit(Xf)
        self._fit_standardized(self.scaler_.transform(Xf))
        return self

    def score(self, X: np.ndarray) -> np.ndarray:
        """Return one OOD score per state (higher = farther from the fit data)."""
        if self.scaler_ is None:
            raise ValueError(f"{type(self).__name__}.score called before fit; call fit(id_states) first.")
        Xf = _as_2d(X, "X (states to score)")
        d = self.scaler_.n_features_in_
        if Xf.shape[1] != d:
            raise ValueError(
                f"{type(self).__name__}.score got states with {Xf.shape[1]} features but was fit on {d}; "
                "score states from the same environment and preprocessing."
            )
        return self._score_standardized(self.scaler_.transform(Xf))


class MahalanobisDetector(_Detector):
    """Mahalanobis distance to the ID states, after standardizing each feature.

    ``covariance="ledoit_wolf"`` (default) shrinks the covariance towards a scaled
    identity so it stays invertible when states are many-dimensional or features are
    collinear (e.g. constant joints); ``"empirical"`` is the plain MLE covariance and
    needs more states than features. The covariance is a d x d matrix: for raw
    image states (d in the tens of thousands) prefer ``KNNDetector``.
    """

    def __init__(self, covariance: Literal["ledoit_wolf", "empirical"] = "ledoit_wolf") -> None:
        super().__init__()
        if covariance not in ("ledoit_wolf", "empirical"):
            raise ValueError(f"covariance must be 'ledoit_wolf' or 'empirical', got {covariance!r}.")
        self.covariance = covariance
        self.cov_: EmpiricalCovariance | None = None
        self.min_fit_samples_reason = (
            "the empirical covariance is singular with fewer states than features + 1"
            if covariance == "empirical"
            else "a covariance needs at least two states"
        )

    def _min_fit_samples(self, n_features: int) -> int:
        return n_features + 1 if self.covariance == "empirical" else 2

    def _fit_standardized(self, Z: np.ndarray) -> None:
        est = EmpiricalCovariance() if self.covariance == "empirical" else LedoitWolf()
        self.cov_ = est.fit(Z)

    def _score_standardized(self, Z: np.ndarray) -> np.ndarray:
        # sklearn returns the *squared* distance; take the root so scores are distances.
        return np.sqrt(np.maximum(self.cov_.mahalanobis(Z), 0.0))


class KNNDetector(_Detector):
    """Euclidean distance (standardized features) to the k nearest ID states.

    ``aggregate="kth"`` scores by the distance to the k-th neighbour (Sun et al.,
    2022), ``"mean"`` by the mean distance to the k neighbours.
    """

    def __init__(self, k: int = 5, aggregate: Literal["kth", "mean"] = "kth") -> None:
        super().__init__()
        if int(k) != k or k < 1:
            raise ValueError(f"k must be a positive integer, got {k!r}.")
        if aggregate not in ("kth", "mean"):
            raise ValueError(f"aggregate must be 'kth' or 'mean', got {aggregate!r}.")
        self.k = int(k)
        self.aggregate = aggregate
        self.nn_: NearestNeighbors | None = None
        self.min_fit_samples_reason = "k neighbours must exist"

    def _min_fit_samples(self, n_features: int) -> int:
        return self.k

    def _fit_standardized(self, Z: np.ndarray) -> None:
        self.nn_ = NearestNeighbors(n_neighbors=self.k).fit(Z)

    def _score_standardized(self, Z: np.ndarray) -> np.ndarray:
        dist, _ = self.nn_.kneighbors(Z, n_neighbors=self.k)
        return dist[:, -1] if self.aggregate == "kth" else dist.mean(axis=1)


def split_fit_eval(
    states: np.ndarray | int, rng: np.random.Generator, fit_fraction: float = 0.5,
    groups: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Randomly split ID states into disjoint (fit_idx, eval_idx) index arrays, each sorted.

    ``states`` is the state array (its first axis is split) or the number of states.
    Detectors are fit on ``fit_idx`` and the ID side of the metrics uses ``eval_idx``.
    With ``groups`` (one label per state, e.g. its episode), whole groups go to one side:
    consecutive states of an episode are near-copies, so a state whose episode-mates sit in
    the fit half is "near" the fit data by construction and a distance detector would be
    flattered. Then ``fit_fraction`` is the share of groups that go to the fit side.
    """
    n = int(states) if np.isscalar(states) else len(states)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}.")
    if not 0.0 < fit_fraction < 1.0:
        raise ValueError(f"fit_fraction must lie strictly between 0 and 1, got {fit_fraction!r}.")
    if groups is not None:
        labels = np.asarray(groups)
        if labels.shape != (n,):
            raise ValueError(f"groups must give one label per state ({n}), got shape {labels.shape}.")
        names, index = np.unique(labels, return_inverse=True)
        n_fit = int(round(fit_fraction * names.size))
        if n_fit < 1 or n_fit > names.size - 1:
            raise ValueError(
                f"split_fit_eval: {names.size} group(s) (episodes) with fit_fraction={fit_fraction} leave an empty fit "
                "or eval part; collect ID states from more episodes (at least 2)."
            )
        fit_groups = rng.permutation(names.size)[:n_fit]
        in_fit = np.isin(index, fit_groups)
        return np.flatnonzero(in_fit), np.flatnonzero(~in_fit)
    n_fit = int(round(fit_fraction * n))
    if n_fit < 1 or n_fit > n - 1:
        raise ValueError(
            f"split_fit_eval: {n} states with fit_fraction={fit_fraction} leaves an empty fit or eval part; "
            "pass more states or a fit_fraction nearer 0.5."
        )
    perm = rng.permutation(n)
    return np.sort(perm[:n_fit]), np.sort(perm[n_fit:])
