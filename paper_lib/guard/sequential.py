"""Sequential statistics over an episode's scores, offline (a whole path) and online (step by step).

A single noisy state should not stop an agent. Both statistics smooth the per-state score:
``WindowMean(w)`` averages the last w scores (no value, hence no alarm, before w steps),
``Cusum(drift)`` accumulates the excess of the scores over ``drift`` and forgets short bursts.
The offline ``path`` (used to calibrate on whole episodes) and the online ``Online*`` trackers
(used while acting) compute the same numbers; tests check that they agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from paper_lib.guard.conformal import check_drift, check_window


@dataclass(frozen=True)
class WindowMean:
    """Mean of the last ``window`` scores of the episode."""

    window: int = 10

    def __post_init__(self) -> None:
        object.__setattr__(self, "window", check_window(self.window))

    @property
    def label(self) -> str:
        return f"window{self.window}"

    def path(self, scores: np.ndarray) -> np.ndarray:
        s = np.asarray(scores, dtype=float).reshape(-1)
        out = np.full(s.size, -np.inf)
        if s.size >= self.window:
            out[self.window - 1:] = sliding_window_view(s, self.window).mean(axis=1)
        return out

    def online(self, n_envs: int) -> OnlineWindow:
        return OnlineWindow(self.window, n_envs)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "window", "window": self.window}


@dataclass(frozen=True)
class Cusum:
    """One-sided CUSUM S_t = max(0, S_{t-1} + s_t - drift) of the episode's scores.

    ``drift`` is a typical ID score level: choose it from ID states that are not in the
    calibration episodes (``from_reference``), or the calibration episodes would not be
    exchangeable with the test episodes any more.
    """

    drift: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "drift", check_drift(self.drift))

    @classmethod
    def from_reference(cls, reference_scores: np.ndarray, quantile: float = 0.9) -> Cusum:
        """drift = the ``quantile`` of ID scores held out from the calibration episodes."""
        ref = np.asarray(reference_scores, dtype=float).reshape(-1)
        if ref.size == 0 or not np.all(np.isfinite(ref)):
            raise ValueError("Cusum.from_reference needs finite scores of held-out ID states (at least one).")
        if not 0.0 < quantile < 1.0:
            raise ValueError(f"quantile={quantile!r}: give a level strictly between 0 and 1, e.g. 0.9.")
        return cls(float(np.quantile(ref, quantile)))

    @property
    def label(self) -> str:
        return "cusum"

    def path(self, scores: np.ndarray) -> np.ndarray:
        s = np.asarray(scores, dtype=float).reshape(-1)
        out = np.empty(s.size)
        acc = 0.0
        for t, x in enumerate(s):  # a recursion: no closed vectorized form
            acc = max(0.0, acc + x - self.drift)
            out[t] = acc
        return out

    def online(self, n_envs: int) -> OnlineCusum:
        return OnlineCusum(self.drift, n_envs)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "cusum", "drift": self.drift}


Statistic = WindowMean | Cusum


def statistic_from_dict(data: dict[str, Any] | None) -> Statistic | None:
    if data is None:
        return None
    if data.get("kind") == "window":
        return WindowMean(int(data["window"]))
    if data.get("kind") == "cusum":
        return Cusum(float(data["drift"]))
    raise ValueError(f"unknown sequential statistic {data!r}; the guard file may come from a newer paper_lib.")


class OnlineWindow:
    """Per-env ring buffers of the last ``window`` scores."""

    def __init__(self, window: int, n_envs: int) -> None:
        self.window = window
        self.buffer = np.zeros((n_envs, window))
        self.count = np.zeros(n_envs, dtype=np.int64)

    def reset(self, mask: np.ndarray) -> None:
        self.count[mask] = 0

    def update(self, scores: np.ndarray) -> np.ndarray:
        rows = np.arange(len(scores))
        self.buffer[rows, self.count % self.window] = scores
        self.count += 1
        full = self.count >= self.window
        # order the ring oldest -> newest so the mean sums in the same order as the offline path
        order = (self.count[:, None] + np.arange(self.window)[None]) % self.window
        means = np.take_along_axis(self.buffer, order, axis=1).mean(axis=1)
        return np.where(full, means, -np.inf)


class OnlineCusum:
    """Per-env CUSUM accumulators."""

    def __init__(self, drift: float, n_envs: int) -> None:
        self.drift = drift
        self.acc = np.zeros(n_envs)

    def reset(self, mask: np.ndarray) -> None:
        self.acc[mask] = 0.0

    def update(self, scores: np.ndarray) -> np.ndarray:
        self.acc = np.maximum(0.0, self.acc + scores - self.drift)
        return self.acc.copy()
