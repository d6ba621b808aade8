"""The properties that make it the paper's method: groups, buffer assignment, members, save/load."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from sb3_contrib import TRPO
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy

from conftest import TINY
from paper_lib import MEMBER_METHODS, METHODS, make_agent, member_outputs, uncertainty
from paper_lib.methods.groups import MEMBER_TAG, member_of_env, tag_observation

ENVS = ["CartPole-v1", "HalfCheetah-v5", "SeaquestNoFrameskip-v4"]


def tiny_agent(method: str, env_id: str = "CartPole-v1", algo: str = "ppo", **kwargs):
    overrides = dict(TINY)
    if algo == "a2c":
        overrides = {"n_steps": 8}
    if algo == "trpo":
        overrides = {"n_steps": 16, "batch_size": 32}
    n_envs = kwargs.pop("n_envs", 4 if "NoFrameskip" in env_id else 8)
    return make_agent(algo, method, env_id, seed=0, overrides=overrides, n_envs=n_envs, **kwargs)


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize("method", METHODS)
def test_every_method_trains_and_predicts(method, env_id):
    model = tiny_agent(method, env_id)
    model.learn(128 if "NoFrameskip" in env_id else 256)
    obs = model.env.reset()
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape[0] == model.env.num_envs
    assert all(model.action_space.contains(a) for a in actions)
    if method != "baseline":
        out = member_outputs(model.policy, obs)
        assert out.values.shape == (4, model.env.num_envs)
        assert not np.allclose(out.values[0], out.values[1]), "members must differ"
        assert not np.allclose(out.action_params[0], out.action_params[1])


@pytest.mark.parametrize("method", ["masksembles", "ensemble"])
@pytest.mark.parametrize("env_id", ["CartPole-v1", "HalfCheetah-v5"])
def test_group_g_acts_with_member_g(method, env_id):
    """The log-prob stored for each rollout action is the acting group's member's, not another's."""
    model = tiny_agent(method, env_id)
    model.learn(128)  # one rollout and one update
    model.collect_rollouts(model.env, _NullCallback(), model.rollout_buffer, model.n_steps)  # no update after it
    buf = model.rollout_buffer
    n_steps, n_envs = buf.buffer_size, buf.n_envs
    obs = th.as_tensor(buf.observations.reshape(n_steps * n_envs, -1))
    actions = th.as_tensor(buf.actions.reshape(n_steps * n_envs, -1))
    with th.no_grad():
        pi, _ = model.policy.member_outputs_from_tensor(obs)
        per_member = th.stack([
            model.policy.action_dist.proba_distribution(pi[m], *([model.policy.log_std] if env_id != "CartPole-v1" else []))
            .log_prob(actions.squeeze(-1) if env_id == "CartPole-v1" else actions) for m in range(4)])
    stored = th.as_tensor(buf.log_probs.reshape(-1))
    acting = th.as_tensor(member_of_env(np.tile(np.arange(n_envs), n_steps), n_envs, 4))
    expected = per_member[acting, th.arange(len(acting))]
    assert th.allclose(stored.float(), expected.float(), atol=1e-4)
    other = per_member[(acting + 1) % 4, th.arange(len(acting))]
    assert not th.allclose(stored.float(), other.float(), atol=1e-4)


def _record_update_batches(model) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Run one update; per minibatch record (observations, evaluated log-probs, every member's log-probs).

    Member log-probs are computed inside the call, i.e. with the weights of that minibatch."""
    records = []
    original = model.policy.evaluate_actions
    dist = model.policy.action_dist

    def recording(obs, actions):
        values, log_prob, entropy = original(obs, actions)
        with th.no_grad():
            pi, _ = model.policy.member_outputs_from_tensor(obs)
            per_member = th.stack([dist.proba_distribution(pi[m], model.policy.log_std).log_prob(actions)
                                   for m in range(pi.shape[0])])
        records.append((obs.numpy().copy(), log_prob.detach().numpy().copy(), per_member.numpy()))
        return values, log_prob, entropy

    model.policy.evaluate_actions = recording
    model.train()
    model.policy.evaluate_actions = original
    return records


def _group_of_rows(model, rows: np.ndarray) -> np.ndarray:
    buf = model.rollout_buffer
    flat = buf.observations.reshape(-1, rows.shape[-1])  # already swapped: env-major after get()
    env_major = buf.observations.shape[0] == buf.buffer_size * buf.n_envs
    assert env_major
    index = {row.tobytes(): i for i, row in enumerate(flat)}
    flat_idx = np.array([index[r.tobytes()] for r in rows])
    env = flat_idx // buf.buffer_size
    return member_of_env(env, buf.n_envs, 4)


@pytest.mark.parametrize("assignment", ["own", "shared"])
def test_update_assigns_transitions_to_members(assignment):
    """own: chunk j holds only member j's transitions; shared: chunk j mixes groups.

    In both, chunk j is evaluated by member j (checked against member j's own log-prob)."""
    model = tiny_agent("ensemble", "HalfCheetah-v5", assignment=assignment)
    model.learn(128)  # one rollout and one update
    model.policy.set_training_mode(False)
    model.collect_rollouts(model.env, _NullCallback(), model.rollout_buffer, model.n_steps)
    records = _record_update_batches(model)
    mixed = False
    for obs, log_prob, per_member in records:
        groups = _group_of_rows(model, obs)
        chunk_member = np.repeat(np.arange(4), len(obs) // 4)
        if assignment == "own":
            assert (groups == chunk_member).all()
        mixed |= bool((groups != chunk_member).any())
        np.testing.assert_allclose(log_prob, per_member[chunk_member, np.arange(len(obs))], atol=1e-4)
    assert mixed == (assignment == "shared")


class _NullCallback:
    def on_rollout_start(self): ...
    def on_rollout_end(self): ...
    def update_locals(self, _): ...
    def on_step(self): return True


def test_truncated_episode_bootstraps_with_its_members_value():
    model = tiny_agent("ensemble", "HalfCheetah-v5")
    obs = model.env.reset()[:1]
    with th.no_grad():
        all_values = model.policy.member_outputs_from_tensor(th.as_tensor(obs))[1][:, 0]
        for member in range(4):
            tensor = model.policy.obs_to_tensor(tag_observation(obs[0], member))[0]
            assert getattr(tensor, MEMBER_TAG) == member
            assert th.allclose(model.policy.predict_values(tensor)[0, 0], all_values[member])
        with pytest.raises(ValueError, match="multiple of k"):
            model.policy.predict_values(th.as_tensor(obs))


def test_time_limit_truncation_runs_through_member_bootstrap():
    """Pendulum always ends by truncation at 200 steps: training must bootstrap each env with its member."""
    from stable_baselines3.common.env_util import make_vec_env

    from paper_lib.methods.groups import MemberGroupVecEnv
    from paper_lib.methods.policy import MemberActorCriticPolicy

    env = MemberGroupVecEnv(make_vec_env("Pendulum-v1", 4, seed=0), 4)
    model = PPO(MemberActorCriticPolicy, env, n_steps=64, batch_size=64, n_epochs=1, seed=0,
                policy_kwargs={"method": "ensemble", "hidden_sizes": (16,)})
    tags = []
    original = model.policy.predict_values
    model.policy.predict_values = lambda obs: tags.append(getattr(obs, MEMBER_TAG, None)) or original(obs)
    model.learn(4 * 256)
    assert sorted(t for t in tags if t is not None) == [0, 1, 2, 3], "one truncation per env, each with its member"


@pytest.mark.parametrize("method", MEMBER_METHODS)
def test_save_load_gives_identical_outputs(tmp_path, method):
    model = tiny_agent(method, "HalfCheetah-v5")
    model.learn(128)
    model.policy.set_inference("single", member=2)
    obs = model.env.reset()
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = PPO.load(path)
    assert loaded.policy.inference == ("single", 2)
    if method in ("masksembles", "ensemble"):
        th.manual_seed(0)
        before = member_outputs(model.policy, obs)
        after = member_outputs(loaded.policy, obs)
        np.testing.assert_array_equal(before.values, after.values)
        np.testing.assert_array_equal(before.action_params, after.action_params)
        np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    else:  # stochastic methods: same weights, and the same outputs under the same torch seed
        for (name, a), (_, b) in zip(model.policy.state_dict().items(), loaded.policy.state_dict().items()):
            assert th.equal(a, b), name
        th.manual_seed(3)
        before = member_outputs(model.policy, obs)
        th.manual_seed(3)
        after = member_outputs(loaded.policy, obs)
        np.testing.assert_array_equal(before.values, after.values)


def test_masksembles_masks_are_in_the_state_dict_and_follow_the_seed():
    a = tiny_agent("masksembles", "HalfCheetah-v5")
    masks = {k: v for k, v in a.policy.state_dict().items() if k.endswith("masks")}
    assert len(masks) == 4  # two layers in each of the policy and value MLPs
    for m in masks.values():
        assert m.shape == (4, 384) and m.sum(1).min() > 0
        assert (m.sum(0) > 0).all(), "the union of the masks covers every unit"
    b = tiny_agent("masksembles", "HalfCheetah-v5")
    for key in masks:
        assert th.equal(masks[key], b.policy.state_dict()[key])
    c = make_agent("ppo", "masksembles", "HalfCheetah-v5", seed=1, overrides=TINY)
    assert any(not th.equal(masks[k], c.policy.state_dict()[k]) for k in masks)


@pytest.mark.parametrize("algo,cls", [("a2c", A2C), ("trpo", TRPO)])
@pytest.mark.parametrize("method", ["masksembles", "ensemble"])
def test_a2c_and_trpo_run_unchanged(algo, cls, method):
    model = tiny_agent(method, "CartPole-v1", algo=algo)
    assert isinstance(model, cls)
    model.learn(256)
    mean, _ = evaluate_policy(model, model.get_env(), n_eval_episodes=2)
    assert np.isfinite(mean)


class LineSearchLog(BaseCallback):
    """Records TRPO's per-update line-search outcome (1 = the policy moved, 0 = step rejected)."""

    def __init__(self):
        super().__init__()
        self.successes: list[float] = []

    def _on_rollout_start(self) -> None:
        logged = self.model.logger.name_to_value
        if "train/is_line_search_success" in logged:
            self.successes.append(float(logged["train/is_line_search_success"]))

    def _on_step(self) -> bool:
        return True


@pytest.mark.parametrize("method", ["mc_dropout", "mc_dropconnect"])
def test_trpo_updates_policies_that_draw_masks(method):
    """With fresh masks per forward pass, sb3-contrib's TRPO rejects every MC Dropout step (KL to
    itself > target) and crashes MC DropConnect (NaN step size); one mask set per update fixes both."""
    model = tiny_agent(method, "HalfCheetah-v5", algo="trpo")
    log = LineSearchLog()
    model.learn(128 * 6, callback=log)
    assert len(log.successes) >= 4 and all(s == 1.0 for s in log.successes)
    assert all(th.isfinite(p).all() for p in model.policy.parameters())


def test_trpo_trains_deterministic_policies_as_sb3_contrib():
    params = []
    for plain in (False, True):  # built and trained one after the other: the same seeds and RNG stream
        model = tiny_agent("masksembles", "HalfCheetah-v5", algo="trpo")
        if plain:
            model.__class__ = TRPO
        model.learn(256)
        params.append([p.detach().clone() for p in model.policy.parameters()])
    assert all(th.equal(a, b) for a, b in zip(*params, strict=True))
    assert not all(th.equal(a, b) for a, b in zip(params[0], tiny_agent("masksembles", "HalfCheetah-v5",
                                                                          algo="trpo").policy.parameters()))


def test_walker_uses_vecnormalize_and_evaluates(tmp_path):
    from stable_baselines3.common.vec_env import VecNormalize

    model = make_agent("ppo", "masksembles", "Walker2d-v5", seed=0, overrides=TINY, tensorboard_log=str(tmp_path))
    assert isinstance(model.get_env().venv, VecNormalize)
    model.learn(256, progress_bar=True)
    mean, _ = evaluate_policy(model, model.get_env(), n_eval_episodes=1)
    assert np.isfinite(mean)
    assert any(tmp_path.iterdir()), "TensorBoard log written"


def test_inference_modes():
    model = tiny_agent("ensemble", "CartPole-v1")
    model.learn(128)
    obs = model.env.reset()
    pi, _ = model.policy.member_outputs_from_tensor(th.as_tensor(obs))
    for member in range(4):
        model.policy.set_inference("single", member)
        np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], pi[member].argmax(-1).numpy())
    model.policy.set_inference("average")
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0],
                                  th.softmax(pi, -1).mean(0).argmax(-1).numpy())
    model.policy.set_inference("vote")
    votes = model.predict(obs, deterministic=True)[0]
    member_actions = pi.argmax(-1).numpy()
    for i, action in enumerate(votes):
        counts = np.bincount(member_actions[:, i], minlength=2)
        assert counts[action] == counts.max()
    with pytest.raises(ValueError, match="inference mode"):
        model.policy.set_inference("median")


def test_deterministic_vote_repeats_itself_on_a_tie():
    """2 vs 2 votes: the tied action with the higher averaged probability, every call; random ties stay an option."""
    from paper_lib.methods.policy import combine_actions

    model = tiny_agent("ensemble", "CartPole-v1")
    logits = th.tensor([[[5.0, 0.0]], [[5.0, 0.0]], [[0.0, 1.0]], [[0.0, 1.0]]]).repeat(1, 200, 1)  # 2 vs 2
    first = combine_actions(logits, model.policy, "vote", None, deterministic=True)
    assert (first == 0).all(), "action 0 is tied on votes and more probable on average"
    logits[:2], logits[2:] = th.tensor([1.0, 0.0]), th.tensor([0.0, 5.0])  # 2 vs 2, action 1 more probable on average
    assert (combine_actions(logits, model.policy, "vote", None, deterministic=True) == 1).all()
    random = combine_actions(logits, model.policy, "vote", None, deterministic=True, ties="random")
    assert 0.3 < random.float().mean() < 0.7
    logits[3] = th.tensor([5.0, 0.0])  # 3 vs 1: the majority, whatever the probabilities
    assert (combine_actions(logits, model.policy, "vote", None, deterministic=True, ties="random") == 0).all()
    # through predict: repeated calls on the same states give the same actions, ties included
    model.policy.set_inference("vote")
    obs = np.random.default_rng(0).normal(size=(256, 4)).astype(np.float32)
    pi, _ = model.policy.member_outputs_from_tensor(th.as_tensor(obs))
    counts = np.stack([np.bincount(a, minlength=2) for a in pi.argmax(-1).numpy().T])
    assert (counts[:, 0] == counts[:, 1]).any(), "the test needs states with tied votes"
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])


def test_sampled_discrete_actions_come_from_the_averaged_distribution():
    """Every member prefers action 0 with p = 0.7: the averaged distribution samples it 70% of the time."""
    from paper_lib.methods.policy import combine_actions

    model = tiny_agent("ensemble", "CartPole-v1")
    logits = th.log(th.tensor([0.7, 0.3])).expand(4, 20_000, 2).clone()
    th.manual_seed(0)
    for mode in ("vote", "average"):
        share = (combine_actions(logits, model.policy, mode, None, deterministic=False) == 0).float().mean()
        assert share.item() == pytest.approx(0.7, abs=0.015), mode
    votes = combine_actions(logits, model.policy, "vote", None, deterministic=False, vote_sampling="member_votes")
    # majority of 4 samples, ties by mean probability (action 0): P = 0.7^4 + 4*0.7^3*0.3 + 6*0.7^2*0.3^2 = 0.9163
    assert (votes == 0).float().mean().item() == pytest.approx(0.9163, abs=0.015)


def test_inference_options_are_saved_and_old_checkpoints_load(tmp_path):
    import zipfile

    model = tiny_agent("ensemble", "CartPole-v1")
    model.policy.set_inference("vote", ties="random", vote_sampling="member_votes")
    model.save(tmp_path / "new.zip")
    loaded = PPO.load(tmp_path / "new.zip")
    assert loaded.policy.inference == ("vote", None)
    assert loaded.policy.inference_options == {"ties": "random", "vote_sampling": "member_votes"}
    # a checkpoint saved before the options existed: its policy state dict lacks both buffers
    with zipfile.ZipFile(tmp_path / "new.zip") as src, zipfile.ZipFile(tmp_path / "old.zip", "w") as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "policy.pth":
                import io

                state = th.load(io.BytesIO(data))
                for key in ("_inference_ties", "_inference_vote_sampling"):
                    del state[key]
                buffer = io.BytesIO()
                th.save(state, buffer)
                data = buffer.getvalue()
            dst.writestr(item, data)
    old = PPO.load(tmp_path / "old.zip")
    assert old.policy.inference_options == {"ties": "mean_prob", "vote_sampling": "average"}
    with pytest.raises(ValueError, match="tie rule"):
        model.policy.set_inference("vote", ties="coin")


def test_continuous_combined_action_is_the_mean_of_member_means():
    model = tiny_agent("ensemble", "HalfCheetah-v5")
    obs = model.env.reset()
    pi, _ = model.policy.member_outputs_from_tensor(th.as_tensor(obs))
    expected = np.clip(pi.mean(0).detach().numpy(), -1, 1)
    np.testing.assert_allclose(model.predict(obs, deterministic=True)[0], expected, atol=1e-6)


def test_uncertainty_shapes_and_baseline_error():
    model = tiny_agent("masksembles", "HalfCheetah-v5")
    obs = np.random.default_rng(0).normal(size=(37, 17)).astype(np.float32)
    u = uncertainty(model.policy, obs)
    assert set(u) == {"value_std", "policy_std", "policy_js"}
    assert all(v.shape == (37,) and (v >= 0).all() for v in u.values())
    base = tiny_agent("baseline", "CartPole-v1")
    assert set(uncertainty(base.policy, np.zeros((3, 4), np.float32))) == {"max_prob", "entropy"}
    with pytest.raises(ValueError, match="members"):
        uncertainty(base.policy, np.zeros((3, 4), np.float32), ("value_std",))
    assert uncertainty(tiny_agent("baseline", "HalfCheetah-v5").policy, obs) == {}


def test_ensemble_members_start_from_different_weights():
    from paper_lib.methods.layers import MemberConv2d, MemberLinear

    for ortho in (True, False):
        linear = MemberLinear(8, 16, k=4, mode="ensemble", ortho_init=ortho)
        conv = MemberConv2d(4, 8, 3, 1, k=4, mode="ensemble", ortho_init=ortho)
        for weight in (linear.weight, conv.weight):
            for a in range(4):
                for b in range(a + 1, 4):
                    assert not th.allclose(weight[a], weight[b]), (ortho, a, b)
    model = tiny_agent("ensemble", "HalfCheetah-v5")
    first = model.policy.mlp_extractor.policy_tower[0].weight
    assert all(not th.equal(first[0], first[m]) for m in range(1, 4))


def test_mc_methods_sample_members_in_one_pass_and_dropconnect_drops_weights():
    from paper_lib.methods.layers import MemberLinear

    layer = MemberLinear(8, 64, k=4, mode="dropconnect", p=0.5)
    with th.no_grad():
        layer.bias.fill_(0.25)
        x = th.zeros(4, 1, 8)
        x[..., 3] = 1.0  # one active input: dropped weights show as outputs equal to the bias
        y = layer(x)[:, 0]
    at_bias = (y == 0.25)
    assert at_bias.any() and (~at_bias).any(), "some weights dropped, not the whole activation"
    assert not th.equal(at_bias[0], at_bias[1]), "each member copy draws its own weight mask"


def test_masks_follow_the_reference_generation():
    from masksembles.common import generation_wrapper

    from paper_lib.methods.layers import generate_masksembles_masks

    ours = generate_masksembles_masks(64, 4, 2.0, seed=7)
    np.random.seed(7)
    reference = generation_wrapper(64, 4, 2.0)
    np.testing.assert_array_equal(ours, reference)
    assert ours.sum(1).tolist() == [34] * 4


@pytest.mark.parametrize("kwargs,match", [
    ({"algo": "sac"}, "unknown algorithm"),
    ({"method": "bayes"}, "unknown method"),
    ({"env_id": "Hopper-v5"}, "unknown environment"),
    ({"n_envs": 6}, "n_envs=6 is not a multiple"),
    ({"overrides": {"batch_size": 30}}, "batch_size=30 is not a multiple"),
    ({"n_members": 1}, "k >= 2"),
    ({"dropout_p": 1.0, "method": "mc_dropout"}, r"outside \[0, 1\)"),
    ({"masksembles_scale": 7.0}, "outside \\[1, 6\\]"),
    ({"overrides": {"n_stepz": 3}}, "unknown override"),
    ({"assignment": "mine"}, "unknown assignment"),
])
def test_bad_input_fails_before_training(kwargs, match):
    args = {"algo": "ppo", "method": "masksembles", "env_id": "CartPole-v1", **kwargs}
    with pytest.raises(ValueError, match=match):
        make_agent(args.pop("algo"), args.pop("method"), args.pop("env_id"), **args)


def test_masksembles_width_too_small_is_rejected():
    from paper_lib.methods.policy import MemberActorCriticPolicy
    from stable_baselines3.common.env_util import make_vec_env

    with pytest.raises(ValueError, match="width >= 10"):
        PPO(MemberActorCriticPolicy, make_vec_env("CartPole-v1", 4), policy_kwargs={"hidden_sizes": (8, 8)})


@pytest.mark.parametrize("p", [0.05, 0.1, 0.5])
def test_keep_mask_drops_each_entry_with_probability_p(p):
    from paper_lib.methods.layers import bernoulli_keep_mask

    th.manual_seed(0)
    mask = bernoulli_keep_mask((200, 1000), p, th.device("cpu"))
    dropped = (mask == 0).float()
    assert abs(dropped.mean().item() - p) < 0.005
    assert th.allclose(mask[mask != 0], th.tensor(1 / (1 - p)))
    # rows are independent draws: their drop rates spread like a binomial, not identical
    assert dropped.mean(1).std().item() == pytest.approx((p * (1 - p) / 1000) ** 0.5, rel=0.25)


@pytest.mark.parametrize("env_id", ["CartPole-v1", "HalfCheetah-v5"])
def test_act_with_uncertainty_equals_predict_plus_uncertainty(env_id):
    from paper_lib.measures.estimates import act_with_uncertainty

    model = tiny_agent("ensemble", env_id)
    obs = model.env.reset()
    actions, scores = act_with_uncertainty(model.policy, obs, deterministic=True)
    np.testing.assert_array_equal(actions, model.predict(obs, deterministic=True)[0])
    for name, value in uncertainty(model.policy, obs).items():
        np.testing.assert_allclose(scores[name], value, rtol=1e-6)
    single, _ = act_with_uncertainty(model.policy, obs[0], deterministic=True)
    np.testing.assert_array_equal(single, model.predict(obs[0], deterministic=True)[0])


@pytest.mark.parametrize("assignment", ["shared", "own"])
def test_a_batch_larger_than_the_rollout_is_one_minibatch_split_over_members(assignment):
    # SB3 trains the baseline on one minibatch of the whole rollout when batch_size exceeds it (Walker2d's
    # 4 envs with a sampled n_steps 64 and batch_size 512); the member methods do the same instead of refusing.
    model = make_agent("ppo", "ensemble", "CartPole-v1", 0, n_envs=4, n_members=2, assignment=assignment,
                       overrides={"n_steps": 16, "batch_size": 128, "n_epochs": 1}).learn(64)
    assert model.num_timesteps == 64 and model.rollout_buffer.buffer_size * 4 == 64
    if assignment == "own":
        buffer = model.rollout_buffer
        (minibatch,) = buffer.member_ordered_indices(128).reshape(1, -1)  # one minibatch: the whole rollout
        assert sorted(minibatch.tolist()) == list(range(64))
        for j, chunk in enumerate(minibatch.reshape(2, -1)):  # flat index = env * n_steps + step
            assert (member_of_env(chunk // buffer.buffer_size, 4, 2) == j).all()
