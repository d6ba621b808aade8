"""The limit column: multiply-adds counted from a network's shapes against a hand count, and the measured limit.

Timings here assert only an order (a limit with 64x the arithmetic takes longer), never an absolute time.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest
from gymnasium import spaces

from conftest import TINY
from paper_lib import make_agent
from paper_lib.bench.arithmetic import MEMBER_WEIGHTS, STATE_WEIGHTS, Count, Op, measurement_count, network_count
from paper_lib.bench.limits import chunk_states, dense_limit
from paper_lib.methods.networks import MemberMLP, MemberNatureCNN, MemberSpec

K, OBS, ACT, H = 2, 3, 2, 12


def _mlp_policy(method: str) -> SimpleNamespace:
    net = MemberMLP(OBS, ACT, [H, H], MemberSpec(method, n_members=K))
    return SimpleNamespace(mlp_extractor=net, observation_space=spaces.Box(-1, 1, (OBS,)))


def _kept(mask) -> tuple[int, int]:
    """(units each member keeps, units some member keeps), read off the masks."""
    return int(mask.masks.sum(1)[0]), int((mask.masks.sum(0) > 0).sum())


def _tower_by_hand(method: str, tower, d_out: int) -> int:
    if method == "masksembles":
        (kept0, union0), (kept1, _) = _kept(tower[2]), _kept(tower[5])
        return OBS * union0 + K * kept0 * kept1 + K * kept1 * d_out  # first layer once, then kept units only
    if method == "ensemble":
        return K * (OBS * H + H * H + H * d_out)
    return OBS * H + K * (H * H + H * d_out)  # MC: the shared first layer once, k samples after it


@pytest.mark.parametrize("method", ["masksembles", "mc_dropout", "mc_dropconnect", "ensemble"])
def test_mlp_counts_equal_a_hand_count(method):
    policy = _mlp_policy(method)
    net = policy.mlp_extractor
    actor = network_count(policy, critic=False)
    both = network_count(policy)
    assert actor.macs == _tower_by_hand(method, net.policy_tower, ACT)
    assert both.macs == actor.macs + _tower_by_hand(method, net.value_tower, 1)
    masks = {"mc_dropout": 2 * (K * H + K * H),  # two dropout layers per tower, k x width each
             "mc_dropconnect": 2 * K * (H * H) + K * H * ACT + K * H * 1}  # every masked weight, per member
    assert both.mask_elements == masks.get(method, 0)
    if method == "mc_dropconnect":
        assert {op.weights for op in both.ops if op.copies > 1} == {STATE_WEIGHTS}  # after the first layers
        assert both.mask_draws == pytest.approx(both.mask_elements * 0.10536, rel=1e-3)  # -ln(0.9)


def _conv(c_out: int, c_in: int, kernel: int, positions: int) -> int:
    return c_out * c_in * kernel * kernel * positions


@pytest.mark.parametrize("method", ["masksembles", "mc_dropout", "mc_dropconnect", "ensemble"])
def test_nature_cnn_counts_equal_a_hand_count(method):
    """A 2 x 36 x 36 image: conv1 8x8/4 -> 8x8 positions, conv2 4x4/2 -> 3x3, conv3 3x3/1 -> 1x1, fc 64 -> 32."""
    net = MemberNatureCNN((2, 36, 36), 3, MemberSpec(method, n_members=K), features_dim=32)
    policy = SimpleNamespace(mlp_extractor=net, observation_space=spaces.Box(0, 255, (2, 36, 36)))
    conv1, conv2, conv3 = _conv(32, 2, 8, 64), _conv(64, 32, 4, 9), _conv(64, 64, 3, 1)
    if method == "masksembles":
        (kept1, union1), (kept_fc, _) = _kept(net.after_conv1), _kept(net.after_fc)
        trunk = _conv(union1, 2, 8, 64) + K * (_conv(64, kept1, 4, 9) + conv3 + 64 * kept_fc)
        heads = K * kept_fc * (3 + 1)
    elif method == "ensemble":
        trunk, heads = K * (conv1 + conv2 + conv3 + 64 * 32), K * 32 * (3 + 1)
    else:
        trunk, heads = conv1 + K * (conv2 + conv3 + 64 * 32), K * 32 * (3 + 1)
    assert network_count(policy).macs == trunk + heads
    assert network_count(policy, critic=False).macs == trunk + heads - K * (kept_fc if method == "masksembles" else 32)


def test_plain_policies_count_each_layer_once_and_the_measurements_pick_their_heads():
    """SB3's MlpPolicy on CartPole (4 -> 64 -> 64 -> 2 actions, a separate value net); its measures read the action
    distribution only (discrete: max_prob, entropy), a member policy's need the values too."""
    policy = make_agent("ppo", "baseline", "CartPole-v1", overrides=dict(TINY)).policy
    actor = 4 * 64 + 64 * 64 + 64 * 2
    assert measurement_count(policy, "predict_b1", discrete=True).macs == actor
    assert measurement_count(policy, "uncertainty_b4096", discrete=True).macs == actor
    assert network_count(policy).macs == 2 * actor - 64 * 2 + 64 * 1
    assert measurement_count(policy, "train_steps_per_s", discrete=True) is None
    member = _mlp_policy("ensemble")
    assert measurement_count(member, "act_uncertainty_b1", discrete=False).macs == network_count(member).macs


def test_conv_positions_and_counts_add_up():
    op = Op(2, 4, 32, MEMBER_WEIGHTS, kernel=8, stride=4, in_hw=(84, 84))
    assert op.out_hw == (20, 20) and op.macs == 2 * 32 * 4 * 64 * 400
    total = Count((Op(1, 3, 5),)) + Count((Op(2, 5, 1),), mask_elements=10, drop_p=0.1)
    assert total.macs == 15 + 10 and total.mask_elements == 10


def _fastest(limit, tries: int = 5) -> float:
    limit.run()
    best = float("inf")
    for _ in range(tries):
        started = time.perf_counter()
        limit.run()
        best = min(best, time.perf_counter() - started)
    return best * limit.scale


def test_the_measured_limit_grows_with_the_count_and_scales_its_chunks():
    small = Count((Op(1, 64, 64),))
    large = Count((Op(64, 64, 64, MEMBER_WEIGHTS),))  # 64x the multiply-adds
    assert _fastest(dense_limit(large, 256)) > _fastest(dense_limit(small, 256))
    limit = dense_limit(large, 256, budget=64 * 128 * 16)  # 16 states' operands per chunk
    assert (limit.states, limit.scale) == (16, 16.0)
    assert chunk_states(large, 8) == 8  # a batch that fits is timed whole


def test_every_kind_of_op_and_the_mask_work_run():
    count = Count((Op(1, 2, 4, kernel=3, stride=1, in_hw=(6, 6)), Op(2, 4, 4, MEMBER_WEIGHTS, kernel=2, in_hw=(4, 4)),
                   Op(2, 4, 3, STATE_WEIGHTS, kernel=2, in_hw=(3, 3)), Op(2, 12, 5, STATE_WEIGHTS),
                   Op(2, 5, 5)), mask_elements=100, drop_p=0.1)
    limit = dense_limit(count, 3)
    limit.run()
    assert limit.states * limit.scale == 3
