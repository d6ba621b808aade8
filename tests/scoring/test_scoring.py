"""Scores you can trust: per-state MC samples, batch-independent and seeded scoring, input checks, score_run."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import torch as th
from scipy.stats import ks_2samp

from conftest import TINY
from paper_lib import act_with_uncertainty, make_agent, member_outputs, paper_hyperparameters, uncertainty
from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.measures.estimates import policy_features
from paper_lib.methods.layers import MCDropout, MemberConv2d, MemberLinear, per_state_masks
from paper_lib.ood.collect import ActionMode, collect_id_states, collect_mujoco_ood_states
from paper_lib.ood.datasets import StateDataset, concat
from paper_lib.scoring.ood_scores import score_run, summarize_seeds

MC_METHODS = ["mc_dropconnect", "mc_dropout"]


def agent(method: str, env_id: str = "HalfCheetah-v5", width: int | None = None):
    """A tiny agent; `width` narrows its MLPs for tests that score many thousand states."""
    hp = paper_hyperparameters(env_id)
    hp["normalize_obs"] = False  # scoring of raw observations; normalized runs: test_score_run_on_a_vecnormalize_run
    if width is not None:
        hp["hidden_sizes"] = [width, width]
    return make_agent("ppo", method, env_id, seed=0, overrides=dict(TINY), hyperparameters=hp)


@pytest.fixture(scope="module")
def states() -> np.ndarray:
    return np.random.default_rng(0).normal(size=(1024, 17)).astype(np.float32)


@pytest.mark.parametrize("method", MC_METHODS)
def test_the_same_state_repeated_in_one_batch_gets_distinct_scores(method):
    """One sample per (member, state): 256 copies of a state are 256 independent MC draws."""
    policy = agent(method).policy
    state = np.random.default_rng(1).normal(size=(1, 17)).astype(np.float32)
    repeated = np.repeat(state, 256, axis=0)
    for scores in (uncertainty(policy, repeated)["value_std"], act_with_uncertainty(policy, repeated)[1]["value_std"],
                   policy_features(policy, repeated)):
        assert len(np.unique(scores, axis=0)) > 250
    with th.no_grad():  # predict's members too
        pi, _ = policy.member_outputs_from_tensor(th.as_tensor(repeated))
    assert len(np.unique(pi[0, :, 0].numpy())) > 250


@pytest.mark.parametrize("method", MC_METHODS)
def test_batch_composition_does_not_change_a_states_scores(method, states):
    """With a fixed seed: the same scores in any batching; across seeds: the same distribution alone or in a batch."""
    policy = agent(method, width=32).policy
    by_batch = [uncertainty(policy, states, seed=3, batch_size=b) for b in (1024, 64)]
    by_batch.append(uncertainty(policy, states[:64], seed=3, batch_size=1))  # each state in its own pass
    for other in by_batch[1:]:
        for name, values in by_batch[0].items():
            np.testing.assert_allclose(other[name], values[:len(other[name])], rtol=1e-5, atol=1e-7)
    alone = uncertainty(policy, states[:1], seed=3)  # a state's seed depends on its position, not its company
    np.testing.assert_allclose(alone["value_std"], by_batch[0]["value_std"][:1], rtol=1e-5)
    assert not np.allclose(uncertainty(policy, states, seed=4)["value_std"], by_batch[0]["value_std"])
    # the state scored alone under 150 seeds vs the same state at random places in batches of 64 and 1024
    target = states[5]
    scored_alone = [uncertainty(policy, target[None], seed=s)["value_std"][0] for s in range(150)]
    in_batches = []
    rng = np.random.default_rng(0)
    for s in range(150):
        size = 64 if s % 4 else 1024
        batch = states[rng.permutation(len(states))[:size]].copy()
        where = int(rng.integers(size))
        batch[where] = target
        in_batches.append(uncertainty(policy, batch, seed=1000 + s)["value_std"][where])
    assert ks_2samp(scored_alone, in_batches).pvalue > 0.001


def test_dropconnect_drops_single_weights_per_state():
    """All-ones weights and inputs: each output counts its kept weights. Dropping whole input units would
    make all outputs of a state equal; dropping output units would make them 0 or full."""
    layer = MemberLinear(64, 32, k=4, mode="dropconnect", p=0.5)
    with th.no_grad():
        layer.weight.fill_(1.0)
        layer.bias.zero_()
        x = th.ones(4, 3, 64)
        with per_state_masks(layer, [11, 12, 13]):
            y = layer(x) * 0.5  # undo the 1/(1-p) rescaling: y = number of kept weights per output
    assert th.equal(y, y.round())
    for member in range(4):
        for state in range(3):
            outputs = y[member, state]
            assert len(th.unique(outputs)) > 3, "outputs differ within a state: single weights are dropped"
            assert ((outputs > 0) & (outputs < 64)).all(), "no output unit is dropped whole"
    assert not th.equal(y[:, 0], y[:, 1]), "each state has its own masks"
    assert not th.equal(y[0], y[1]), "each member has its own masks"
    conv = MemberConv2d(2, 3, 2, 1, k=4, mode="dropconnect", p=0.5)
    with th.no_grad():
        conv.weight.fill_(1.0)
        conv.bias.zero_()
        with per_state_masks(conv, [1, 2]):
            z = conv(th.ones(4, 2, 2, 2, 2)) * 0.5  # one output pixel per channel: kept weights of its kernel
    assert len(th.unique(z)) > 3 and ((z > 0) & (z < 8)).all() and not th.equal(z[:, 0], z[:, 1])


def test_per_state_masks_keep_the_drop_rate():
    layer = MCDropout(0.1)
    with per_state_masks(layer, np.arange(200)):
        y = layer(th.ones(4, 200, 500))
    dropped = (y == 0).float()
    assert dropped.mean().item() == pytest.approx(0.1, abs=0.004)
    assert th.allclose(y[y != 0], th.tensor(1 / 0.9))
    with pytest.raises(ValueError, match="one seed per state"), per_state_masks(layer, [1, 2]):
        layer(th.ones(4, 3, 5))


@pytest.mark.parametrize("bad,match", [
    (np.zeros((3, 5), np.float32), r"shape \(3, 5\)"),
    (np.zeros((0, 17), np.float32), r"N >= 1"),
    (np.full((2, 17), np.nan, np.float32), "NaN or inf in 2 of 2"),
])
def test_observations_are_checked(bad, match):
    policy = agent("masksembles").policy
    for call in (uncertainty, member_outputs, policy_features, act_with_uncertainty):
        with pytest.raises(ValueError, match=match):
            call(policy, bad)
    single, _ = act_with_uncertainty(policy, np.zeros(17, np.float32))  # one state without a batch axis is fine
    assert single.shape == (6,)


# ---------------------------------------------------------------------------------------- score_run

SHORT = {"max_episode_steps": 20, "skip_first": 2}


def _dataset(model, env_id, vecnormalize=None):
    mode = ActionMode(deterministic=False, inference="vote")
    id_states = collect_id_states(model, env_id, action_mode=mode, seed=1, episodes=4, steps_per_episode=10,
                                  vecnormalize=vecnormalize, **SHORT)
    ood = collect_mujoco_ood_states(model, env_id, action_mode=mode, seed=2, configs=3, steps_per_config=10,
                                    vecnormalize=vecnormalize, **SHORT)
    return concat(id_states, ood)


def test_score_run_on_a_vecnormalize_run(tmp_path):
    """Walker2d normalizes observations: the noise OOD set needs the checkpoint's saved normalizer."""
    walker = make_agent("ppo", "mc_dropout", "Walker2d-v5", seed=0, overrides=dict(TINY))
    walker.learn(128)
    walker.get_vec_normalize_env().save(str(tmp_path / "vecnormalize.pkl"))
    (tmp_path / "config.json").write_text(json.dumps(walker.paper_lib_config))
    data = _dataset(walker, "Walker2d-v5", walker.get_vec_normalize_env())
    assert data.policy_obs is not None
    checkpoint = Checkpoint(walker, walker.paper_lib_config, tmp_path / "vecnormalize.pkl", tmp_path)
    run = score_run(checkpoint, data, 0, 30, n_scoring_seeds=2)
    assert set(run.metrics.ood_set) == {"perturbed", "noise"}
    assert {"value_std", "policy_std", "knn_obs", "mahalanobis_features"} <= set(run.metrics.measure)
    assert np.isfinite(run.metrics[["auroc", "auroc_ci_low", "auroc_ci_high"]].to_numpy()).all()
    member = run.metrics[run.metrics.measure == "value_std"]
    assert (member.n_scoring_seeds == 2).all() and (member.auroc_scoring_std > 0).all()
    assert (run.metrics[run.metrics.measure == "knn_obs"].auroc_scoring_std == 0).all()


@pytest.fixture(scope="module")
def cheetah_run():
    model = agent("mc_dropconnect", width=32)
    model.learn(128)
    return model, _dataset(model, "HalfCheetah-v5")


def test_score_run_is_seeded_and_separates_fit_and_eval_episodes(cheetah_run):
    model, data = cheetah_run
    th.manual_seed(123)  # the global torch RNG must not matter
    a = score_run(model, data, 0, 30, n_scoring_seeds=2)
    th.manual_seed(456)
    b = score_run(model, data, 0, 30, n_scoring_seeds=2)
    assert a.metrics.equals(b.metrics) and a.replicates.equals(b.replicates)
    c = score_run(model, data, 1, 30, n_scoring_seeds=2)
    value = a.metrics.measure == "value_std"
    assert not np.allclose(a.metrics[value].auroc, c.metrics[value].auroc)
    # the evaluated ID states are whole episodes, half of them; the fit half is the rest
    id_eval = a.scores[(a.scores.label == 0) & (a.scores.ood_set == "perturbed")]
    assert id_eval.episode.nunique() == 2 and len(id_eval) == 20
    # OOD is the positive class: noise far outside the ID range scores high for a distance detector
    knn = a.metrics[(a.metrics.measure == "knn_obs") & (a.metrics.ood_set == "noise")]
    assert knn.auroc.item() > 0.9
    assert (a.metrics.ci == "cluster").all() and (a.metrics.n_id_clusters == 2).all()
    assert (a.metrics[a.metrics.ood_set == "perturbed"].n_ood_clusters == 3).all()


def test_identical_ood_configurations_are_resampled_as_one_cluster(cheetah_run):
    """The third configuration made a redraw of the first (same physics, another env seed): the bootstrap
    sees 2 OOD conditions, not 3; the AUROCs (point estimates) stay exactly as they were."""
    model, data = cheetah_run
    first = json.loads(data.configs[0])
    redraw = json.dumps({**first, "seed": first["seed"] + 1}, sort_keys=True)
    merged = StateDataset(**{**{k: getattr(data, k) for k in ("states", "labels", "source", "config_index", "episode",
                                                               "step", "metadata")},
                             "configs": [*data.configs[:2], redraw]})
    a, b = score_run(model, data, 0, 30), score_run(model, merged, 0, 30)
    perturbed = a.metrics.ood_set == "perturbed"
    assert (a.metrics[perturbed].n_ood_clusters == 3).all() and (b.metrics[perturbed].n_ood_clusters == 2).all()
    assert a.metrics.auroc.equals(b.metrics.auroc) and a.metrics[~perturbed].equals(b.metrics[~perturbed])
    assert not np.allclose(a.metrics[perturbed].auroc_ci_low, b.metrics[perturbed].auroc_ci_low)


def test_summarize_seeds_pools_seeds_and_clusters(cheetah_run):
    model, data = cheetah_run
    runs = [score_run(model, data, s, 40, n_scoring_seeds=2) for s in (0, 1)]
    metrics = [r.metrics.assign(env="HalfCheetah-v5", method="mc_dropconnect", seed=s) for s, r in enumerate(runs)]
    reps = [r.replicates.assign(env="HalfCheetah-v5", method="mc_dropconnect", seed=s) for s, r in enumerate(runs)]
    one = summarize_seeds(metrics[0], reps[0], np.random.default_rng(0), 200)
    row = metrics[0].set_index(["ood_set", "measure"])
    for _, r in one.iterrows():  # one seed: the run's own numbers and interval
        assert r.auroc == pytest.approx(row.loc[(r.ood_set, r.measure), "auroc"])
        assert r.auroc_ci_low == pytest.approx(row.loc[(r.ood_set, r.measure), "auroc_ci_low"])
    both = summarize_seeds(pd.concat(metrics, ignore_index=True), pd.concat(reps, ignore_index=True),
                           np.random.default_rng(0), 200)
    assert (both.n_seeds == 2).all() and both.auroc_seed_std.notna().all()
    assert (both.auroc_ci_low <= both.auroc_ci_high).all()
