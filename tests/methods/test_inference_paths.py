"""The lean path's two ways on many states (`inference.PATHS`): "fast" gives the "exact" path's numbers up to
float rounding, a state's scores do not depend on the batch it is scored in, and the gathered weights both
reuse across calls follow every change of the weights and masks.

"exact" is the path every committed score was computed with; that it still gives those bits was checked by
scoring real checkpoints with the code before and after (issue 70's report); here, that it never runs a piece
of the fast path.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from torch import nn

from paper_lib.measures.estimates import act_with_uncertainty, member_outputs, policy_features, uncertainty
from paper_lib.methods import inference
from paper_lib.methods.networks import MEMBER_METHODS
from test_fast_inference import CASES, assert_close, build_policy, policy_for, seeds_for, states

MANY = 150  # above COMPACT_MIN_STATES: where the paths differ


@pytest.mark.parametrize("kind,method", CASES)
def test_the_fast_path_equals_the_exact_path_and_the_reference(kind, method):
    policy = policy_for(kind, method)
    obs_array = states(policy, MANY, seed=5)
    obs = policy.obs_to_tensor(obs_array)[0]
    seeds = seeds_for(policy, MANY)
    with th.no_grad():
        fast = inference.fast_members(policy, obs, seeds, path="fast")
        exact = inference.fast_members(policy, obs, seeds, path="exact")
        reference = inference.reference_members(policy, obs, seeds)
        for ours, other, ref, what in zip(fast, exact, reference, ("action params", "values")):
            if kind != "atari" and method in ("masksembles", "ensemble"):
                assert ours.is_contiguous(), f"{what}: contiguous, as the measures read them fastest"
            assert_close(ours, other, f"{kind} {method} {what} fast vs exact")
            assert_close(ours, ref, f"{kind} {method} {what} fast vs reference")
        assert_close(inference.fast_last_hidden(policy, obs, seeds, path="fast"),
                     inference.reference_last_hidden(policy, obs, seeds), "features")
    fast_scores = uncertainty(policy, obs_array, seed=3, path="fast")
    exact_scores = uncertainty(policy, obs_array, seed=3)
    assert fast_scores.keys() == exact_scores.keys()
    for name in exact_scores:
        assert_close(fast_scores[name], exact_scores[name], name)
        assert fast_scores[name].dtype == exact_scores[name].dtype
    assert_close(member_outputs(policy, obs_array, seed=3, path="fast").values,
                 member_outputs(policy, obs_array, seed=3).values)
    assert_close(policy_features(policy, obs_array, seed=3, path="fast"), policy_features(policy, obs_array, seed=3))


@pytest.mark.parametrize("path", inference.PATHS)
@pytest.mark.parametrize("kind,method", [("mujoco", m) for m in MEMBER_METHODS] + [("atari", "masksembles"),
                                                                                   ("discrete", "mc_dropout")])
def test_a_states_scores_do_not_depend_on_its_batch(kind, method, path):
    """The same states and seed scored in batches of 1, 7 (exact arithmetic), 64, 100 and 1024 (the path's own)."""
    policy = policy_for(kind, method)
    obs = states(policy, 70 if kind == "atari" else 200, seed=6)
    alone = uncertainty(policy, obs, seed=9, batch_size=1024, path=path)
    for batch_size in (1, 7, 64, 100):
        if kind == "atari" and batch_size == 1:
            continue  # 70 single-image passes: slow, and batch 7 already mixes the sizes
        scores = uncertainty(policy, obs, seed=9, batch_size=batch_size, path=path)
        for name in alone:
            assert_close(scores[name], alone[name], f"{name} batch {batch_size}")
    seeds = seeds_for(policy, len(obs))
    with th.no_grad():  # a slice of states among other states: the same outputs as the slice alone
        tensor = policy.obs_to_tensor(obs)[0]
        whole, _ = policy.member_outputs_from_tensor(tensor, seeds, path=path)
        part, _ = policy.member_outputs_from_tensor(tensor[2:68], None if seeds is None else seeds[2:68], path=path)
    assert_close(part, whole[:, 2:68], "a slice of the batch")


def _forbid(*args, **kwargs):
    raise AssertionError("the exact path ran a piece of the fast path")


@pytest.mark.parametrize("kind,method", CASES)
def test_the_exact_path_runs_none_of_the_fast_path(kind, method, monkeypatch):
    policy = policy_for(kind, method)
    obs = states(policy, MANY if kind != "atari" else 70)
    calls = []
    for name in ("states_major_tower", "narrow_output"):
        original = getattr(inference, name)
        monkeypatch.setattr(inference, name, lambda *a, _f=original, **k: calls.append(1) or _f(*a, **k))
    uncertainty(policy, obs, seed=1, path="fast")
    if kind != "atari" and method in ("masksembles", "ensemble"):
        assert calls, "the fast path takes states-major towers and features-major heads"
    monkeypatch.setattr(inference, "states_major_tower", _forbid)
    monkeypatch.setattr(inference, "narrow_output", _forbid)
    monkeypatch.setattr(inference, "activate_owned", _forbid)
    uncertainty(policy, obs, seed=1)
    member_outputs(policy, obs, seed=1)
    policy_features(policy, obs, seed=1)


def test_acting_and_scoring_a_few_states_is_the_exact_path(monkeypatch):
    """Below COMPACT_MIN_STATES "fast" is the exact arithmetic: acting with `predict` stays bit for bit."""
    policy = policy_for("mujoco", "masksembles")
    monkeypatch.setattr(inference, "states_major_tower", _forbid)
    monkeypatch.setattr(inference, "activate_owned", _forbid)
    obs = states(policy, inference.COMPACT_MIN_STATES - 1)
    policy.predict(obs, deterministic=True)
    act_with_uncertainty(policy, obs)
    uncertainty(policy, obs, path="fast")


def test_an_unknown_path_is_refused():
    policy = policy_for("mujoco", "ensemble")
    obs = states(policy, 3)
    for call in (lambda: uncertainty(policy, obs, path="quick"), lambda: member_outputs(policy, obs, path="quick"),
                 lambda: policy_features(policy, obs, path="quick")):
        with pytest.raises(ValueError, match="unknown inference path 'quick'.*exact.*fast"):
            call()


@pytest.mark.parametrize("method", MEMBER_METHODS)
def test_other_shapes_of_network_on_the_fast_path(method):
    """k = 3, three hidden layers (the third without a stochastic layer), ReLU: no tanh to take from numpy."""
    policy = build_policy("mujoco", method, n_members=3, hidden_sizes=(64, 48, 32), activation_fn=nn.ReLU,
                          ortho_init=False)
    obs = policy.obs_to_tensor(states(policy, 90))[0]
    seeds = seeds_for(policy, 90)
    with th.no_grad():
        for ours, reference in zip(inference.fast_members(policy, obs, seeds, path="fast"),
                                   inference.reference_members(policy, obs, seeds)):
            assert_close(ours, reference, method)


@pytest.mark.parametrize("path", inference.PATHS)
@pytest.mark.parametrize("kind", ["mujoco", "atari"])
def test_gathered_weights_follow_every_change(kind, path):
    """Gathered Masksembles weights and kept units are reused across calls: an optimizer step, a reload, replaced
    memory and changed masks must all show in the next call."""
    policy = build_policy(kind, "masksembles")
    obs = policy.obs_to_tensor(states(policy, 70))[0]
    net = policy.mlp_extractor

    def check(what: str) -> None:
        with th.no_grad():
            for ours, reference in zip(inference.fast_members(policy, obs, None, path=path),
                                       inference.reference_members(policy, obs, None)):
                assert_close(ours, reference, what)

    check("first call")
    layer = net.policy_tower[3] if kind == "mujoco" else net.conv2
    with th.no_grad():
        layer.weight.mul_(2.0)  # an optimizer step
    check("in-place update")
    state = {name: value.clone() + 0.01 for name, value in policy.state_dict().items() if "masks" not in name
             and value.is_floating_point()}
    policy.load_state_dict(state, strict=False)  # a reload
    check("reload")
    layer.weight.data = layer.weight.data * 3.0  # new memory under the same parameter
    check("replaced memory")
    mask = next(m for m in net.modules() if type(m).__name__ == "MasksemblesMask")
    with th.no_grad():
        mask.masks.copy_(mask.masks.roll(1, dims=0))  # other members keep other units (equal counts)
    check("changed masks")


def test_tanh_from_numpy_leaves_the_observations_alone():
    """The fast path overwrites only activations it made: a tower starting with tanh must not touch the input."""
    policy = build_policy("mujoco", "ensemble")
    policy.mlp_extractor.policy_tower.insert(0, nn.Tanh())
    policy.mlp_extractor.value_tower.insert(0, nn.Tanh())
    obs = policy.obs_to_tensor(states(policy, 80))[0]
    before = obs.clone()
    with th.no_grad():
        pi, _ = inference.fast_members(policy, obs, None, path="fast")
        reference, _ = inference.reference_members(policy, obs, None)
    assert th.equal(obs, before)
    assert_close(pi, reference)
    np.testing.assert_array_equal(obs.numpy(), before.numpy())


@pytest.mark.parametrize("discrete", [True, False])
def test_the_fast_member_stds_equal_the_numpy_measures(discrete):
    """The fast path's stds (mean, deviations, mean square) against the numpy definitions, zero spread included."""
    from paper_lib.measures import definitions as measures

    rng = np.random.default_rng(1)
    values, params = rng.normal(size=(4, 300)).astype(np.float32), (3 * rng.normal(size=(4, 300, 5))).astype(np.float32)
    values[:, 0], params[:, 0] = values[0, 0], params[0, 0]  # identical members: exactly zero
    expected = measures.all_measures(values, params, discrete)
    got = measures.torch_measures(th.as_tensor(values), th.as_tensor(params), discrete, exact=False)
    for name in expected:
        np.testing.assert_allclose(got[name].numpy(), expected[name], rtol=1e-5, atol=1e-6, err_msg=name)
    assert float(got["value_std"][0]) == 0.0 and float(got["policy_std"][0]) == 0.0
