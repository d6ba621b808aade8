"""The budget curve's timed fit is PEDM's fit: the same weights and history, one logged row per epoch."""

from __future__ import annotations

import numpy as np

from paper_lib.experiments.pedm_budget import TimedPEDM, first_episodes
from paper_lib.measures.dynamics import PEDMConfig, PEDMDetector


def _transitions(n_episodes: int = 4, length: int = 30, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n_episodes * length, 3))
    action = rng.uniform(-1, 1, size=(len(obs), 2))
    return {"obs": obs, "action": action, "next_obs": obs + 0.1 * action.sum(1, keepdims=True),
            "episode": np.repeat(np.arange(n_episodes), length)}


def test_the_timed_fit_is_pedms_fit_and_logs_every_epoch():
    config = PEDMConfig(hidden=(8,), decays=(1e-5, 1e-5), epochs=3, n_particles=10)
    data, evaluation, log = _transitions(), _transitions(1, seed=1), []
    probe = {**_transitions(2, seed=2), "label": np.tile((np.arange(30) >= 10).astype(int), 2)}
    timed = TimedPEDM(config, 0, evaluation, log, probes={"x": probe}, probe_epochs=(2,)).fit(
        data["obs"], data["action"], data["next_obs"], data["episode"])
    plain = PEDMDetector(config, seed=0).fit(data["obs"], data["action"], data["next_obs"], data["episode"])
    assert timed.history_ == plain.history_
    assert np.array_equal(timed.score(data["obs"], data["action"], data["next_obs"]),
                          plain.score(data["obs"], data["action"], data["next_obs"]))
    assert [row["epoch"] for row in log] == [1, 2, 3]
    assert [row["val_mse"] for row in log] == [val for _, val in plain.history_]
    assert all(row["eval_mse"] > 0 for row in log)
    assert [("auroc_x" in row) for row in log] == [False, True, False] and 0 <= log[1]["auroc_x"] <= 1
    seconds = [row["seconds"] for row in log]
    assert seconds == sorted(seconds)


def test_first_episodes_keeps_the_first_n():
    data = _transitions()
    assert np.unique(first_episodes(data, 2)["episode"]).tolist() == [0, 1]
