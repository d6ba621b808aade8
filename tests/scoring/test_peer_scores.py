"""The peer detectors end to end on a few real HalfCheetah episodes under PEDM's protocol (tiny sizes)."""

import numpy as np
import pytest

from paper_lib.measures.dynamics import PEDMConfig
from paper_lib.ood.pedm_protocol import play_pedm_episodes
from paper_lib.scoring.metrics import injection_metrics
from paper_lib.scoring.peer_scores import PEER_DETECTORS, episode_observations, fit_peer_detectors, peer_scores

TINY = PEDMConfig(ens_size=2, hidden=(16,), decays=(1e-4, 1e-4), epochs=5, batch_size=64, n_particles=10)


class SineAgent:
    """A deterministic stand-in for a trained agent: actions a smooth function of the observation."""

    def predict(self, obs, deterministic=True):
        return np.sin(np.arange(6) + 10 * obs[0]), None


@pytest.fixture(scope="module")
def collections():
    agent = SineAgent()
    id_data = play_pedm_episodes(agent, "HalfCheetah-v5", None, n_episodes=3, seed=1, max_steps=40)
    ood = play_pedm_episodes(agent, "HalfCheetah-v5", "act_factor", "severe", n_episodes=2, seed=2, max_steps=40,
                             injection_step=20)
    return id_data, ood


def test_every_detector_scores_every_row(collections):
    id_data, ood = collections
    dets = fit_peer_detectors(id_data, seed=0, pedm_config=TINY)
    scores = peer_scores(dets, ood)
    assert set(scores) == set(PEER_DETECTORS)
    for s in scores.values():
        assert s.shape == (len(ood["obs"]),) and np.isfinite(s).all()
    again = peer_scores(fit_peer_detectors(id_data, seed=0, pedm_config=TINY), ood)
    for name in PEER_DETECTORS:
        np.testing.assert_array_equal(scores[name], again[name])
    # One episode scored alone gets the same scores as inside the collection (episode-wise, batch-invariant).
    first = {k: v[ood["episode"] == 0] for k, v in ood.items()}
    alone = peer_scores(dets, first)
    for name in PEER_DETECTORS:
        np.testing.assert_allclose(alone[name], scores[name][ood["episode"] == 0], rtol=1e-5)
    row = injection_metrics(scores["pedm"], ood["label"], ood["episode"])
    assert row["n_episodes"] == 2 and row["n_id"] == row["n_ood"] == 40


def test_episode_observations_end_with_the_last_next_state(collections):
    id_data, _ = collections
    eps, rows = episode_observations(id_data)
    assert len(eps) == 3 and all(len(e) == 41 for e in eps)
    np.testing.assert_array_equal(eps[0][-1], id_data["next_obs"][rows[0][-1]])


def test_bad_input():
    with pytest.raises(ValueError, match="lacks"):
        fit_peer_detectors({"obs": np.zeros((3, 17))}, seed=0)
    with pytest.raises(ValueError, match="one row per transition"):
        peer_scores(None, {"obs": np.zeros((3, 17)), "action": np.zeros((2, 6)), "next_obs": np.zeros((3, 17)),
                           "episode": np.zeros(3)})
