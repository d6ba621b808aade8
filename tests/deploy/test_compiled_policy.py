"""The compiled policy acts and measures as `act_with_uncertainty` does, state by state.

`paper_lib.deploy.compile_policy` copies a Masksembles or Ensemble MLP policy's weights for one-state acting; it
must give the torch path's actions and every measure up to float rounding, for continuous and discrete actions,
both combination modes, one state and a batch; a state's numbers must not depend on its batch; and a policy it does
not cover must fail with one error that names the call to use instead.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from paper_lib.agents.factory import make_agent
from paper_lib.deploy import NotCompilable, compile_policy, kernels
from paper_lib.measures.estimates import act_with_uncertainty
from paper_lib.methods.policy import MemberActorCriticPolicy

SPACES = {
    "continuous": (spaces.Box(-np.inf, np.inf, (17,), np.float32), spaces.Box(-1.0, 1.0, (6,), np.float32)),
    "discrete": (spaces.Box(-np.inf, np.inf, (4,), np.float32), spaces.Discrete(3)),
}
COMPILED = ("masksembles", "ensemble")


def build_policy(kind: str, method: str, inference: str = "vote") -> MemberActorCriticPolicy:
    """A member policy with seeded random weights large enough that every member's outputs differ."""
    obs_space, action_space = SPACES[kind]
    policy = MemberActorCriticPolicy(obs_space, action_space, lambda _: 3e-4, method=method, member_seed=3,
                                     hidden_sizes=(64, 64))
    generator = th.Generator().manual_seed(0)
    with th.no_grad():
        for parameter in policy.parameters():
            parameter.normal_(0.0, 0.3, generator=generator)
    policy.set_inference(inference)
    policy.set_training_mode(False)
    return policy


def states(kind: str, n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, *SPACES[kind][0].shape)).astype(np.float32)


def assert_same(torch_out: tuple, numpy_out: tuple, discrete: bool) -> None:
    (actions, scores), (np_actions, np_scores) = torch_out, numpy_out
    assert np_actions.shape == actions.shape
    if discrete:
        np.testing.assert_array_equal(np_actions, actions)
    else:
        np.testing.assert_allclose(np_actions, actions, rtol=1e-5, atol=1e-6)
    assert set(np_scores) == set(scores)
    for name, value in scores.items():
        assert np_scores[name].shape == value.shape, name
        np.testing.assert_allclose(np_scores[name], value, rtol=1e-4, atol=1e-6, err_msg=name)


@pytest.mark.parametrize("inference", ["vote", "average"])
@pytest.mark.parametrize("kind", list(SPACES))
@pytest.mark.parametrize("method", COMPILED)
def test_compiled_policy_gives_the_torch_paths_actions_and_measures(method: str, kind: str, inference: str) -> None:
    policy = build_policy(kind, method, inference)
    compiled = compile_policy(policy)
    batch = states(kind, 70)
    assert_same(act_with_uncertainty(policy, batch[0]), compiled.act_with_uncertainty(batch[0]), kind == "discrete")
    assert_same(act_with_uncertainty(policy, batch), compiled.act_with_uncertainty(batch), kind == "discrete")
    # the members really differ, so the measures compare something
    assert compiled.act_with_uncertainty(batch)[1]["policy_std"].min() > 0


@pytest.mark.parametrize("method", COMPILED)
def test_a_states_numbers_do_not_depend_on_its_batch(method: str) -> None:
    compiled = compile_policy(build_policy("continuous", method))
    batch = states("continuous", 40)
    actions, scores = compiled.act_with_uncertainty(batch)
    for i in (0, 17, 39):  # the same bits: every state runs the same products, alone or in a batch
        alone_actions, alone = compiled.act_with_uncertainty(batch[i])
        np.testing.assert_array_equal(alone_actions, actions[i])
        for name, value in alone.items():
            np.testing.assert_array_equal(value, scores[name][i:i + 1], err_msg=name)


def test_a_trained_sb3_model_compiles_and_keeps_its_actions_and_measures(tiny_overrides: dict) -> None:
    """Real short PPO training on HalfCheetah, then the algorithm itself (not its policy) is compiled."""
    model = make_agent("ppo", "masksembles", "HalfCheetah-v5", 0, n_envs=4, overrides=tiny_overrides)
    model.learn(64)
    obs = model.env.reset()
    compiled = compile_policy(model)
    assert_same(act_with_uncertainty(model.policy, obs), compiled.act_with_uncertainty(obs), discrete=False)
    model.env.close()


@pytest.mark.parametrize("method", ["mc_dropout", "mc_dropconnect"])
def test_mc_methods_are_refused_with_the_call_to_use_instead(method: str) -> None:
    with pytest.raises(NotCompilable, match="act_with_uncertainty"):
        compile_policy(build_policy("continuous", method))


def test_a_baseline_and_a_cnn_are_refused() -> None:
    baseline = make_agent("ppo", "baseline", "HalfCheetah-v5", 0, n_envs=1).policy
    with pytest.raises(NotCompilable, match="member policy"):
        compile_policy(baseline)
    image = MemberActorCriticPolicy(spaces.Box(0, 255, (4, 84, 84), np.uint8), spaces.Discrete(6), lambda _: 3e-4,
                                    method="masksembles", member_seed=3)
    with pytest.raises(NotCompilable, match="only MLP policies"):
        compile_policy(image)


def test_a_wrong_observation_is_one_clear_error() -> None:
    compiled = compile_policy(build_policy("continuous", "masksembles"))
    with pytest.raises(ValueError, match="observation have shape"):
        compiled.act_with_uncertainty(np.zeros(5, np.float32))


def test_the_compiled_tanh_is_within_a_few_float32_ulps_of_the_exact_one() -> None:
    """The kernels' rational tanh (Eigen's float tanh) against float64 tanh: small x, the polynomial's range, the
    clamp and beyond."""
    x = np.concatenate([np.linspace(-12, 12, 200_001), [0.0, 1e-5, -3e-4, 7.9, 8.0, 50.0, -50.0]]).astype(np.float32)
    compiled = np.array([kernels.tanh(value) for value in x[::97]] + [kernels.tanh(value) for value in x[-7:]],
                        np.float32)
    points = np.concatenate([x[::97], x[-7:]])
    exact = np.tanh(points.astype(np.float64))
    ulps = np.abs(compiled - exact) / np.spacing(np.abs(exact).astype(np.float32))
    assert ulps.max() <= 8, (points[ulps.argmax()], ulps.max())
    np.testing.assert_array_equal(compiled[points == 0], 0.0)
    assert compiled.max() <= 1.0 and compiled.min() >= -1.0
