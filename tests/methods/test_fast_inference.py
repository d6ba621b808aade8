"""The lean inference path gives the reference modules' numbers: outputs, actions, measures, features.

`paper_lib.methods.inference` computes every member's outputs with less work (shared first
layers once, Masksembles members on their kept units, lean per-state MC masks, chunked
images, measures in torch); the reference is the member network's own modules inside
`per_state_masks` (`inference.reference_members`), with SB3's distributions and the numpy
measures. Same seeds must give the same numbers, up to float rounding, for every method, MLP
(continuous and discrete) and CNN, on one state and on many.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import DiagGaussianDistribution
from torch import nn

from paper_lib.measures import definitions as measures
from paper_lib.methods import inference
from paper_lib.methods.networks import MEMBER_METHODS
from paper_lib.methods.policy import MemberActorCriticPolicy, draw_state_seeds
from paper_lib.measures.estimates import (
    act_with_uncertainty,
    member_outputs,
    policy_features,
    uncertainty,
)

SPACES = {
    "mujoco": (spaces.Box(-np.inf, np.inf, (17,), np.float32), spaces.Box(-1.0, 1.0, (6,), np.float32)),
    "discrete": (spaces.Box(-np.inf, np.inf, (4,), np.float32), spaces.Discrete(3)),
    "atari": (spaces.Box(0, 255, (4, 84, 84), np.uint8), spaces.Discrete(6)),
}
CASES = [(kind, method) for kind in SPACES for method in MEMBER_METHODS]
SIZES = [1, 5, 70]  # one state, a few (dense Masksembles), many (Masksembles on kept units: COMPACT_MIN_STATES)


def build_policy(kind: str, method: str, **kwargs) -> MemberActorCriticPolicy:
    """A member policy with random (seeded) weights large enough that every member's outputs matter."""
    obs_space, action_space = SPACES[kind]
    kwargs.setdefault("hidden_sizes", (64, 64))
    policy = MemberActorCriticPolicy(obs_space, action_space, lambda _: 3e-4, method=method, member_seed=3, **kwargs)
    generator = th.Generator().manual_seed(0)
    with th.no_grad():
        for parameter in policy.parameters():
            parameter.normal_(0.0, 0.1, generator=generator)
    policy.set_training_mode(False)
    return policy


_POLICIES: dict[tuple[str, str], MemberActorCriticPolicy] = {}


def policy_for(kind: str, method: str) -> MemberActorCriticPolicy:
    if (kind, method) not in _POLICIES:
        _POLICIES[kind, method] = build_policy(kind, method)
    return _POLICIES[kind, method]


def states(policy: MemberActorCriticPolicy, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    space = policy.observation_space
    if space.dtype == np.uint8:
        return rng.integers(0, 256, size=(n, *space.shape), dtype=np.uint8)
    return rng.normal(size=(n, *space.shape)).astype(np.float32)


def assert_close(ours: th.Tensor | np.ndarray, reference: th.Tensor | np.ndarray, what: str = "") -> None:
    ours, reference = th.as_tensor(np.asarray(ours)), th.as_tensor(np.asarray(reference))
    assert ours.shape == reference.shape, what
    scale = max(1.0, float(reference.abs().max()))
    assert float((ours.double() - reference.double()).abs().max()) <= 1e-5 * scale, what


def seeds_for(policy: MemberActorCriticPolicy, n: int, seed: int = 7) -> np.ndarray | None:
    return draw_state_seeds(n, th.Generator().manual_seed(seed)) if policy.samples_members else None


# --- member outputs ---------------------------------------------------------------------------

@pytest.mark.parametrize("kind,method", CASES)
def test_member_outputs_equal_the_reference_modules(kind, method, monkeypatch):
    monkeypatch.setattr(inference, "IMAGE_CHUNK_STATES", 32)  # 70 images: three chunks
    compact_calls = []
    compact_tower = inference.compact_tower
    monkeypatch.setattr(inference, "compact_tower", lambda *args: compact_calls.append(1) or compact_tower(*args))
    policy = policy_for(kind, method)
    for n in SIZES:
        obs = policy.obs_to_tensor(states(policy, n))[0]
        seeds = seeds_for(policy, n)
        with th.no_grad():
            pi, vf = inference.fast_members(policy, obs, seeds)
            ref_pi, ref_vf = inference.reference_members(policy, obs, seeds)
            assert_close(pi, ref_pi, f"{kind} {method} n={n} action params")
            assert_close(vf, ref_vf, f"{kind} {method} n={n} values")
            hidden = inference.fast_last_hidden(policy, obs, seeds)
            assert_close(hidden, inference.reference_last_hidden(policy, obs, seeds), f"{kind} {method} n={n} features")
            actor_only, no_values = inference.fast_members(policy, obs, seeds, critic=False)
            assert no_values is None
            assert_close(actor_only, ref_pi, "actor only: the value tower's masks do not move the policy's")
    assert bool(compact_calls) == (kind != "atari" and method == "masksembles"), "many states: kept units only"


@pytest.mark.parametrize("kind,method", [c for c in CASES if c[0] != "atari"])
def test_acting_on_a_few_states_is_bit_identical(kind, method):
    """Below COMPACT_MIN_STATES an MLP runs the reference's own arithmetic: a MuJoCo episode acted with
    `predict` follows the same trajectory as before (chaos would amplify any rounding difference)."""
    policy = policy_for(kind, method)
    for n in (1, 5):
        obs = policy.obs_to_tensor(states(policy, n, seed=4))[0]
        seeds = seeds_for(policy, n)
        with th.no_grad():
            for ours, reference in zip(inference.fast_members(policy, obs, seeds),
                                       inference.reference_members(policy, obs, seeds)):
                assert th.equal(ours, reference), (kind, method, n)
            for deterministic in (True, False):
                th.manual_seed(6)
                ours = policy._predict(obs, deterministic)
                th.manual_seed(6)
                assert th.equal(ours, reference_predict(policy, obs, deterministic)), (kind, method, n, deterministic)


@pytest.mark.parametrize("kind,method", CASES)
def test_the_lean_path_runs_without_falling_back(kind, method, monkeypatch):
    """No silent fallback: with the reference switched off, every method still answers."""
    def no_reference(*args, **kwargs):
        raise AssertionError("the lean path fell back to the reference modules")

    monkeypatch.setattr(inference, "reference_members", no_reference)
    monkeypatch.setattr(inference, "reference_last_hidden", no_reference)
    policy = policy_for(kind, method)
    obs = states(policy, 3)
    with th.no_grad():
        policy.member_outputs_from_tensor(policy.obs_to_tensor(obs)[0])
    uncertainty(policy, obs)
    act_with_uncertainty(policy, obs[0])
    policy_features(policy, obs)
    policy.predict(obs, deterministic=True)


def test_with_autograd_on_the_reference_modules_run():
    policy = policy_for("mujoco", "masksembles")
    obs = policy.obs_to_tensor(states(policy, 4))[0]
    pi, vf = policy.member_outputs_from_tensor(obs)
    assert pi.requires_grad and vf.requires_grad, "gradients need the modules (the training path)"
    with th.no_grad():
        lean_pi, _ = policy.member_outputs_from_tensor(obs)
    assert_close(lean_pi, pi.detach())


def test_an_unknown_network_falls_back_to_the_reference(monkeypatch):
    def unsupported(*args, **kwargs):
        raise inference.Unsupported("test")

    policy = policy_for("mujoco", "mc_dropout")
    obs = policy.obs_to_tensor(states(policy, 6))[0]
    seeds = seeds_for(policy, 6)
    with th.no_grad():
        expected = inference.reference_members(policy, obs, seeds)
        monkeypatch.setattr(inference, "fast_members", unsupported)
        got = inference.members(policy, obs, seeds)
    assert th.equal(got[0], expected[0]) and th.equal(got[1], expected[1])


@pytest.mark.parametrize("method", MEMBER_METHODS)
def test_other_shapes_of_network(method):
    """k = 3, three hidden layers (the third without a stochastic layer), ReLU, no ortho init."""
    policy = build_policy("mujoco", method, n_members=3, hidden_sizes=(64, 48, 32), activation_fn=nn.ReLU,
                          ortho_init=False)
    for n in (2, 70):
        obs = policy.obs_to_tensor(states(policy, n))[0]
        seeds = seeds_for(policy, n)
        with th.no_grad():
            for ours, reference in zip(inference.fast_members(policy, obs, seeds),
                                       inference.reference_members(policy, obs, seeds)):
                assert_close(ours, reference, f"{method} n={n}")
            assert_close(inference.fast_last_hidden(policy, obs, seeds),
                         inference.reference_last_hidden(policy, obs, seeds), f"{method} n={n} features")


@pytest.mark.parametrize("kind", ["mujoco", "atari"])
def test_masksembles_masks_with_unequal_counts_run_dense(kind):
    """Kept-unit gathering needs equal counts per mask; other masks still give the reference's numbers."""
    policy = build_policy(kind, "masksembles")
    for mask in (m for m in policy.mlp_extractor.modules() if type(m).__name__ == "MasksemblesMask"):
        first_kept = int(mask.masks[0].nonzero()[0])
        mask.masks[0, first_kept] = 0.0
        assert inference.kept_units(mask) is None
    obs = policy.obs_to_tensor(states(policy, 70))[0]
    with th.no_grad():
        for ours, reference in zip(inference.fast_members(policy, obs, None),
                                   inference.reference_members(policy, obs, None)):
            assert_close(ours, reference)


def test_per_state_draws_equal_the_reference_generators():
    """A re-seeded generator draws what a fresh generator per state and layer draws."""
    from paper_lib.methods.layers import _StateNoise, per_state_dropped
    from paper_lib.methods.per_state import StateSeeds, draw_drops, member_major

    layer = nn.Identity()
    for seeds in ([3, 2**62 - 5, 12345], list(range(1000, 1020))):  # a few states (Python ints) and many (numpy)
        noise = _StateNoise(seeds, stream=2)
        generators = noise.generators(0, len(seeds))
        layer_seeds = StateSeeds(np.array(seeds, dtype=np.uint64), {id(layer): 2}).for_layer(layer)
        assert layer_seeds == [g.initial_seed() for g in generators]
        reference = per_state_dropped(noise.generators(0, len(seeds)), 4, 50, 0.3, th.device("cpu"))
        drawn, counts = draw_drops(layer_seeds, 4 * 50, 0.3)
        assert th.equal(member_major(drawn, counts, 50, th.device("cpu")), reference)


# --- actions ----------------------------------------------------------------------------------

def reference_combine(pi, policy, mode, member, deterministic, ties="mean_prob", vote_sampling="average"):
    """`combine_actions` as it was: every action through SB3's distribution objects."""
    dist = policy.action_dist

    def distribution(params):
        if isinstance(dist, DiagGaussianDistribution):
            return dist.proba_distribution(params, policy.log_std)
        return dist.proba_distribution(action_logits=params)

    if mode == "single":
        m = int(th.randint(pi.shape[0], ())) if member is None else member
        return distribution(pi[m]).get_actions(deterministic=deterministic)
    if isinstance(dist, DiagGaussianDistribution):
        return distribution(pi.mean(0)).get_actions(deterministic=deterministic)
    probs = th.softmax(pi, -1).mean(0)
    if mode == "average" or (not deterministic and vote_sampling == "average"):
        return probs.argmax(-1) if deterministic else th.multinomial(probs, 1).squeeze(-1)
    member_actions = pi.argmax(-1) if deterministic else th.distributions.Categorical(logits=pi).sample()
    counts = nn.functional.one_hot(member_actions, pi.shape[-1]).sum(0).float()
    if ties == "random":
        return (counts + 0.5 * th.rand_like(counts)).argmax(-1)
    tied = counts == counts.max(-1, keepdim=True).values
    return th.where(tied, probs, th.full_like(probs, -1.0)).argmax(-1)


def reference_predict(policy, obs: th.Tensor, deterministic: bool) -> th.Tensor:
    """`_predict` as it was: the modules inside per_state_masks, then the distributions."""
    features = policy.extract_features(obs)
    with policy.per_state_masks(obs.shape[0]):
        pi, _ = policy.mlp_extractor.members(features, "all", critic=False)
    return reference_combine(pi, policy, *policy.inference, deterministic=deterministic, **policy.inference_options)


MODES = [("vote", None), ("average", None), ("single", 2), ("single", None)]


@pytest.mark.parametrize("kind,method", CASES)
def test_predict_equals_the_reference(kind, method):
    """Same torch seed, same actions: deterministic and sampled, every inference mode."""
    policy = policy_for(kind, method)
    obs = policy.obs_to_tensor(states(policy, 24, seed=1))[0]
    try:
        for mode, member in MODES:
            policy.set_inference(mode, member)
            for deterministic in (True, False):
                with th.no_grad():
                    th.manual_seed(5)
                    ours = policy._predict(obs, deterministic)
                    th.manual_seed(5)
                    reference = reference_predict(policy, obs, deterministic)
                if isinstance(policy.action_space, spaces.Discrete):
                    assert th.equal(ours, reference), (mode, member, deterministic)
                else:  # float rounding of the members' means, and of a sample around them
                    assert_close(ours, reference, f"{mode} {member} deterministic={deterministic}")
    finally:
        policy.set_inference("vote")


def test_discrete_vote_options_equal_the_reference():
    policy = policy_for("discrete", "ensemble")
    obs = policy.obs_to_tensor(states(policy, 200))[0]
    for ties, sampling in (("random", "average"), ("mean_prob", "member_votes"), ("random", "member_votes")):
        policy.set_inference("vote", ties=ties, vote_sampling=sampling)
        for deterministic in (True, False):
            with th.no_grad():
                th.manual_seed(9)
                ours = policy._predict(obs, deterministic)
                th.manual_seed(9)
                assert th.equal(ours, reference_predict(policy, obs, deterministic)), (ties, sampling, deterministic)
    policy.set_inference("vote", ties="mean_prob", vote_sampling="average")


# --- measures ---------------------------------------------------------------------------------

def reference_scores(policy, obs: np.ndarray, seeds: np.ndarray | None) -> dict[str, np.ndarray]:
    with th.no_grad():
        pi, vf = inference.reference_members(policy, policy.obs_to_tensor(obs)[0], seeds)
    discrete = isinstance(policy.action_space, spaces.Discrete)
    return measures.all_measures(vf.squeeze(-1).numpy(), pi.numpy(), discrete)


@pytest.mark.parametrize("kind,method", CASES)
def test_uncertainty_and_act_with_uncertainty_equal_the_reference(kind, method):
    policy = policy_for(kind, method)
    obs = states(policy, 70, seed=2)
    expected = reference_scores(policy, obs, draw_state_seeds(70, th.Generator().manual_seed(11))
                                if policy.samples_members else None)
    scores = uncertainty(policy, obs, seed=11, batch_size=64)  # a batch on kept units, a dense one
    assert scores.keys() == expected.keys()
    for name in expected:
        assert_close(scores[name], expected[name], name)
        assert scores[name].dtype == expected[name].dtype, name
    assert uncertainty(policy, obs, ("value_std",), seed=11)["value_std"] == pytest.approx(expected["value_std"],
                                                                                          rel=1e-5, abs=1e-7)
    for batch in (obs[:1], obs[:7]):
        th.manual_seed(4)
        actions, scores = act_with_uncertainty(policy, batch)
        th.manual_seed(4)
        seeds = draw_state_seeds(len(batch)) if policy.samples_members else None
        with th.no_grad():
            pi, vf = inference.reference_members(policy, policy.obs_to_tensor(batch)[0], seeds)
            ref_actions = reference_combine(pi, policy, *policy.inference, deterministic=True,
                                            **policy.inference_options).numpy()
        if isinstance(policy.action_space, spaces.Box):
            ref_actions = np.clip(ref_actions, policy.action_space.low, policy.action_space.high)
        if isinstance(policy.action_space, spaces.Discrete):
            np.testing.assert_array_equal(actions, ref_actions.reshape(actions.shape))
        else:
            assert_close(actions, ref_actions.reshape(actions.shape), "actions")
        discrete = isinstance(policy.action_space, spaces.Discrete)
        for name, value in measures.all_measures(vf.squeeze(-1).numpy(), pi.numpy(), discrete).items():
            assert_close(scores[name], value, f"act_with_uncertainty {name}")


@pytest.mark.parametrize("kind,method", [("mujoco", "masksembles"), ("atari", "mc_dropconnect"),
                                         ("discrete", "mc_dropout")])
def test_member_outputs_and_features_equal_the_reference(kind, method):
    policy = policy_for(kind, method)
    obs = states(policy, 80, seed=3)
    seeds = draw_state_seeds(80, th.Generator().manual_seed(2)) if policy.samples_members else None
    out = member_outputs(policy, obs, batch_size=64, seed=2)
    with th.no_grad():
        pi, vf = inference.reference_members(policy, policy.obs_to_tensor(obs)[0], seeds)
        hidden = inference.reference_last_hidden(policy, policy.obs_to_tensor(obs)[0], seeds).mean(0)
    assert_close(out.action_params, pi.numpy())
    assert_close(out.values, vf.squeeze(-1).numpy())
    assert_close(policy_features(policy, obs, batch_size=64, seed=2), hidden.numpy())


@pytest.mark.parametrize("discrete", [True, False])
def test_torch_measures_equal_the_numpy_measures(discrete):
    rng = np.random.default_rng(0)
    values, params = rng.normal(size=(4, 50)).astype(np.float32), (3 * rng.normal(size=(4, 50, 5))).astype(np.float32)
    params[:, 0] = params[0, 0]  # identical members: zero spread
    expected = measures.all_measures(values, params, discrete)
    got = measures.torch_measures(th.as_tensor(values), th.as_tensor(params), discrete)
    assert got.keys() == expected.keys()
    for name in expected:
        np.testing.assert_allclose(got[name].numpy(), expected[name], rtol=1e-5, atol=1e-6, err_msg=name)
    if discrete:  # a baseline: one member, the distribution measures only
        single = measures.torch_measures(None, th.as_tensor(params[:1]), True)
        assert set(single) == {"max_prob", "entropy"}
        np.testing.assert_allclose(single["entropy"].numpy(), measures.entropy(params[:1]), rtol=1e-5, atol=1e-6)


def test_the_inference_profile_runs():
    from conftest import TINY

    from paper_lib.bench import BenchConfig
    from paper_lib.bench.profile import profile_inference

    config = BenchConfig(envs=("CartPole-v1",), methods=("baseline", "mc_dropout"), overrides=dict(TINY))
    table = profile_inference(config, "CartPole-v1", "mc_dropout", "act", 64, top=3)
    assert "mc_dropout: act on 64 states" in table and len(table.splitlines()) == 5


def test_weights_changed_after_a_call_are_used():
    """Views of the weights are reused between calls: in-place updates, reloads and replaced tensors must show."""
    policy = build_policy("mujoco", "masksembles")
    obs = policy.obs_to_tensor(states(policy, 3))[0]
    layer = policy.mlp_extractor.policy_tower[3]

    def check():
        with th.no_grad():
            assert th.equal(inference.fast_members(policy, obs, None)[0], inference.reference_members(policy, obs, None)[0])

    check()
    with th.no_grad():
        layer.weight.mul_(2.0)  # an optimizer step
    check()
    state = {name: value.clone() + 0.5 for name, value in policy.state_dict().items() if "masks" not in name
             and value.is_floating_point()}
    policy.load_state_dict(state, strict=False)  # a reload
    check()
    layer.weight.data = layer.weight.data * 3.0  # new memory under the same parameter
    layer.bias.data = layer.bias.data + 1.0
    check()
