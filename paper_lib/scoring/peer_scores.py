"""The peer detectors (PEDM, DEEDEE-style, DEXTER-style) fit on ID transitions and scored on a PEDM-protocol collection.

A collection is what `paper_lib.ood.pedm_protocol.play_pedm_episodes` returns: one row per transition
(obs, action, next_obs, label, episode, step). Every detector scores transition t from what has been
seen once s_{t+1} exists: PEDM the transition itself, the episode detectors the episode's observations
s_0..s_{t+1}. s_{t+1} is the first state a perturbation injected at step t can change, so a transition's
label and every detector's score refer to the same moment.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from paper_lib.measures.dynamics import PEDMConfig, PEDMDetector
from paper_lib.measures.sequences import EpisodeMeanDetector, WindowForestDetector

COLUMNS = ("obs", "action", "next_obs", "episode")
PEER_DETECTORS = ("pedm", "episode_mean", "window_forest")


def _check(data: Mapping[str, np.ndarray], name: str) -> None:
    missing = [c for c in COLUMNS if c not in data]
    if missing:
        raise ValueError(f"{name} lacks {missing}; pass what play_pedm_episodes returns.")
    n = len(data["obs"])
    if n == 0 or any(len(data[c]) != n for c in COLUMNS):
        raise ValueError(f"{name}: {COLUMNS} must be non-empty with one row per transition each.")


def episode_observations(data: Mapping[str, np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each episode's observations s_0..s_T (its obs rows, then its last next_obs) and its row indices."""
    ep = np.asarray(data["episode"])
    rows = [np.flatnonzero(ep == e) for e in dict.fromkeys(ep.tolist())]
    obs, nxt = np.asarray(data["obs"]), np.asarray(data["next_obs"])
    return [np.vstack([obs[r], nxt[r[-1:]]]) for r in rows], rows


@dataclass
class PeerDetectors:
    pedm: PEDMDetector
    episode_mean: EpisodeMeanDetector
    window_forest: WindowForestDetector


def fit_peer_detectors(id_data: Mapping[str, np.ndarray], seed: int, pedm_config: PEDMConfig | None = None,
                       device: str = "cpu") -> PeerDetectors:
    """Fit all three on ID transitions (unperturbed episodes, ``kind=None``) held apart from the evaluated ones."""
    _check(id_data, "id_data")
    episodes, _ = episode_observations(id_data)
    pedm = PEDMDetector(pedm_config, seed=seed, device=device).fit(
        id_data["obs"], id_data["action"], id_data["next_obs"], id_data["episode"])
    return PeerDetectors(pedm, EpisodeMeanDetector().fit(episodes), WindowForestDetector(seed=seed).fit(episodes))


def peer_scores(detectors: PeerDetectors, data: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """One score per row of ``data`` for each peer detector (``PEER_DETECTORS``), higher = more likely OOD."""
    _check(data, "data")
    episodes, rows = episode_observations(data)
    out = {"pedm": detectors.pedm.score(data["obs"], data["action"], data["next_obs"])}
    for name in ("episode_mean", "window_forest"):
        scores = np.empty(len(data["obs"]))
        for r, s in zip(rows, getattr(detectors, name).score(episodes)):
            scores[r] = s[1:]  # the score once s_{t+1} is seen
        out[name] = scores
    return out
