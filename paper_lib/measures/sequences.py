"""Detectors that read an episode's recent observations, not one state: DEEDEE-style and DEXTER-style.

Both fit on ID episodes (a list of (T, d) observation arrays) and give one score per step of each
episode they score (higher = more likely OOD). A step's score uses only its own episode, so it does
not depend on which other episodes are scored with it.

- ``EpisodeMeanDetector`` (after DEEDEE, Aljaafari et al., arXiv 2510.21638): the running mean of the
  episode's observations up to step t, scored by its RBF similarity to the ID training summary. The
  paper's exact definition (which summary, which bandwidth, how its two statistics are combined) was
  not findable here; this is the plainest reading of its abstract (docs/deviations.md).
- ``WindowForestDetector`` (after DEXTER, Nasvytis et al., AAMAS 2024, github.com/LinasNas/DEXTER
  ``src/detectors/DEXTER/DEXTER_detector.py``): features of a sliding window of the last 10 observations,
  per observation dimension, one scikit-learn IsolationForest per dimension (l. 163-181, random_state
  2023), the score the mean over dimensions of ``-decision_function`` (l. 228-236). DEXTER's features come
  from tsfresh's EfficientFCParameters (hundreds per dimension, l. 123, 139); ours are seven plain ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.special import logsumexp
from sklearn.ensemble import IsolationForest


def check_episodes(episodes: Sequence[np.ndarray], name: str, min_length: int = 1,
                   n_features: int | None = None) -> list[np.ndarray]:
    """Each episode as a finite (T, d) float array with T >= min_length and one d for all, or a ValueError."""
    if isinstance(episodes, np.ndarray):
        raise ValueError(f"{name} must be a list of (T, d) episode arrays, not one array; "
                         "split a flat array with `episodes_of(states, episode_ids)`.")
    out = [np.asarray(ep, dtype=float) for ep in episodes]
    if not out:
        raise ValueError(f"{name} holds no episodes; pass at least one.")
    for i, ep in enumerate(out):
        if ep.ndim != 2:
            raise ValueError(f"{name}[{i}] must be a (T, d) array of observations, got shape {ep.shape}.")
        if len(ep) < min_length:
            raise ValueError(f"{name}[{i}] has {len(ep)} step(s) but at least {min_length} are needed.")
        if not np.all(np.isfinite(ep)):
            raise ValueError(f"{name}[{i}] contains NaN/inf values; drop or fix those steps first.")
    dims = {ep.shape[1] for ep in out} | ({n_features} if n_features is not None else set())
    if len(dims) != 1:
        raise ValueError(f"{name}: episodes must all have the fitted number of features, got {sorted(dims)}.")
    return out


def episodes_of(states: np.ndarray, episode_ids: np.ndarray) -> list[np.ndarray]:
    """Split a flat (n, d) array into episodes, in order of first appearance, rows kept in their order."""
    ids = np.asarray(episode_ids)
    if ids.shape != (len(states),):
        raise ValueError(f"episode_ids must give one id per state ({len(states)}), got shape {ids.shape}.")
    return [np.asarray(states)[ids == e] for e in dict.fromkeys(ids.tolist())]


def running_means(ep: np.ndarray) -> np.ndarray:
    """m_t = mean(x_0..x_t) for every t."""
    return np.cumsum(ep, axis=0) / np.arange(1, len(ep) + 1)[:, None]


class EpisodeMeanDetector:
    """Score of step t: -log of the mean RBF similarity of the episode's running mean m_t to the ID summary.

    Observations are standardized with the ID steps' mean and std. The summary at step t is the ID
    training episodes' running means at the same step (an episode shorter than t contributes its last
    one), so an agent's usual start-up transient is ID. The bandwidth ``sigma`` defaults to the median
    heuristic: sigma^2 = half the median squared distance between training running means at equal t.
    The score is -log(mean_j exp(-|m_t - c_j(t)|^2 / (2 sigma^2))), monotone in the similarity but
    free of its saturation at 0 far from the data (no ties among far states).
    """

    def __init__(self, sigma: float | None = None) -> None:
        if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
            raise ValueError(f"sigma must be a positive number or None (median heuristic), got {sigma!r}.")
        self.sigma = sigma
        self.summary_: list[np.ndarray] | None = None

    def fit(self, episodes: Sequence[np.ndarray]) -> "EpisodeMeanDetector":
        eps = check_episodes(episodes, "episodes (ID training)")
        if len(eps) < 2 and self.sigma is None:
            raise ValueError("EpisodeMeanDetector.fit needs at least 2 ID episodes for the median-heuristic "
                             "bandwidth; pass more episodes or a fixed sigma.")
        steps = np.concatenate(eps)
        self.mu_, sd = steps.mean(axis=0), steps.std(axis=0)
        self.sd_ = np.where(sd < 1e-12, 1.0, sd)
        self.summary_ = [running_means((ep - self.mu_) / self.sd_) for ep in eps]
        self.sigma_ = self.sigma if self.sigma is not None else self._median_sigma()
        return self

    def _at(self, t: np.ndarray) -> np.ndarray:
        """The summary at steps t: (len(t), n_episodes, d)."""
        return np.stack([m[np.minimum(t, len(m) - 1)] for m in self.summary_], axis=1)

    def _median_sigma(self) -> float:
        longest = max(len(m) for m in self.summary_)
        c = self._at(np.arange(longest))
        iu = np.triu_indices(c.shape[1], k=1)
        d2 = np.concatenate([((ct[:, None, :] - ct[None, :, :]) ** 2).sum(-1)[iu] for ct in c])
        med = float(np.median(d2))
        return float(np.sqrt(med / 2.0)) if med > 0 else 1.0

    def score(self, episodes: Sequence[np.ndarray]) -> list[np.ndarray]:
        if self.summary_ is None:
            raise ValueError("EpisodeMeanDetector.score called before fit; call fit(ID episodes) first.")
        out = []
        for ep in check_episodes(episodes, "episodes", n_features=len(self.mu_)):
            m = running_means((ep - self.mu_) / self.sd_)
            d2 = ((m[:, None, :] - self._at(np.arange(len(ep)))) ** 2).sum(-1)  # (T, n_episodes)
            out.append(np.log(d2.shape[1]) - logsumexp(-d2 / (2.0 * self.sigma_ ** 2), axis=1))
        return out


FEATURES = ("mean", "std", "min", "max", "median", "slope", "mean_abs_change")


def window_features(window: np.ndarray) -> np.ndarray:
    """(n, w, d) windows -> (n, d, 7) features: mean, std, min, max, median, least-squares slope, mean |change|."""
    w = window.shape[1]
    t = np.arange(w) - (w - 1) / 2.0
    slope = np.einsum("t,ntd->nd", t, window) / (t ** 2).sum()
    change = np.abs(np.diff(window, axis=1)).mean(axis=1)
    return np.stack([window.mean(1), window.std(1), window.min(1), window.max(1), np.median(window, axis=1),
                     slope, change], axis=-1)


def sliding_windows(ep: np.ndarray, w: int) -> np.ndarray:
    """(T, d) -> (T - w + 1, w, d): the window ending at each step from w - 1 on."""
    return np.lib.stride_tricks.sliding_window_view(ep, w, axis=0).transpose(0, 2, 1)


def causal_windows(ep: np.ndarray, w: int) -> np.ndarray:
    """(T, d) -> (T, w, d): the window ending at every step, its first state repeated where fewer than w precede."""
    return sliding_windows(np.concatenate([np.repeat(ep[:1], w - 1, axis=0), ep]), w)


class WindowForestDetector:
    """DEXTER-S: per-dimension isolation forests on features of the last ``window`` observations.

    Step t (t >= window - 1) is scored by the window ending at t; the first window - 1 steps get the
    first window's score, as DEXTER does (``DEXTER_detector.py`` l. 238-243: it looks up to window - 1
    steps ahead there). Episodes need at least ``window`` steps. With ``causal=True`` no step looks ahead:
    every step's window ends at it, the episode's first observation repeated in front where fewer than
    ``window`` precede (`causal_windows`), in fitting as in scoring, so episodes of any length are scored.
    """

    def __init__(self, window: int = 10, n_estimators: int = 100, seed: int = 2023, causal: bool = False) -> None:
        if isinstance(window, bool) or not isinstance(window, int) or window < 2:
            raise ValueError(f"window must be an integer >= 2 (a slope needs two steps), got {window!r}.")
        self.window, self.n_estimators, self.seed, self.causal = window, int(n_estimators), int(seed), bool(causal)
        self.forests_: list[IsolationForest] | None = None

    @property
    def _min_length(self) -> int:
        return 1 if self.causal else self.window

    def _features(self, eps: list[np.ndarray]) -> list[np.ndarray]:
        windows = causal_windows if self.causal else sliding_windows
        return [window_features(windows(ep, self.window)) for ep in eps]

    def fit(self, episodes: Sequence[np.ndarray]) -> "WindowForestDetector":
        eps = check_episodes(episodes, "episodes (ID training)", min_length=self._min_length)
        feats = np.concatenate(self._features(eps))  # (n_windows, d, 7)
        if len(feats) < 2:
            raise ValueError(f"WindowForestDetector.fit got {len(feats)} window(s); an isolation forest needs at "
                             "least 2: pass longer or more ID episodes.")
        self.n_features_ = feats.shape[1]
        self.forests_ = [IsolationForest(n_estimators=self.n_estimators, random_state=self.seed).fit(feats[:, j])
                         for j in range(self.n_features_)]
        return self

    def score(self, episodes: Sequence[np.ndarray]) -> list[np.ndarray]:
        if self.forests_ is None:
            raise ValueError("WindowForestDetector.score called before fit; call fit(ID episodes) first.")
        eps = check_episodes(episodes, "episodes", min_length=self._min_length, n_features=self.n_features_)
        out = []
        for feats in self._features(eps):
            s = np.mean([-f.decision_function(feats[:, j]) for j, f in enumerate(self.forests_)], axis=0)
            out.append(s if self.causal else np.concatenate([np.full(self.window - 1, s[0]), s]))
        return out
