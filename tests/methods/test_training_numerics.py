"""Training numerics are frozen: the library's layers train bit for bit like the layers the runs were trained with.

Inference and scoring sample MC masks per (member, state) (paper_lib.methods.layers.per_state_masks);
training must keep drawing exactly what it drew before: one DropConnect mask per member per
forward pass, the same number of random numbers, the same updates. A frozen copy of the layers
(tests/_frozen_training_layers.py) trains the same agent from the same seed; every parameter,
the rollout and update outputs and the truncated-episode bootstrap values must be identical.
"""

from __future__ import annotations

import pytest
import torch as th

import _frozen_training_layers as frozen
from conftest import TINY
from paper_lib import make_agent
from paper_lib.methods import networks
from paper_lib.methods.groups import tag_observation


def _train(env_id: str, method: str) -> dict[str, th.Tensor]:
    """2 rollouts + 2 updates from seed 0, then the training-path outputs under a fixed torch seed."""
    atari = "NoFrameskip" in env_id
    model = make_agent("ppo", method, env_id, seed=0, overrides=TINY, n_envs=4 if atari else 8)
    model.learn(2 * TINY["n_steps"] * model.n_envs)
    out = {f"param/{name}": p.detach().clone() for name, p in model.policy.named_parameters()}
    obs = model.env.reset()
    th.manual_seed(1)
    with th.no_grad():
        for training in (True, False):
            model.policy.set_training_mode(training)
            for member in range(4):  # SB3's bootstrap of a truncated episode, tagged with its member
                tensor = model.policy.obs_to_tensor(tag_observation(obs[member], member))[0]
                out[f"bootstrap/{training}/{member}"] = model.policy.predict_values(tensor)
            actions, values, log_prob = model.policy(model.policy.obs_to_tensor(obs)[0])  # rollout's forward
            ev, elp, ent = model.policy.evaluate_actions(model.policy.obs_to_tensor(obs)[0], actions)  # update's
            out[f"forward/{training}"] = th.cat([actions.float().flatten(), values.flatten(), log_prob.flatten()])
            out[f"evaluate/{training}"] = th.cat([ev.flatten(), elp.flatten()])
    out["rng_after"] = th.rand(4)  # the same number of random numbers was drawn
    return out


CASES = [(env, method) for env in ("CartPole-v1", "HalfCheetah-v5")
         for method in ("ensemble", "mc_dropconnect", "mc_dropout", "masksembles")]
CASES += [("SeaquestNoFrameskip-v4", "mc_dropconnect"), ("SeaquestNoFrameskip-v4", "mc_dropout")]


@pytest.mark.parametrize("env_id,method", CASES)
def test_training_is_bit_identical_to_the_frozen_layers(env_id, method, monkeypatch):
    ours = _train(env_id, method)
    with monkeypatch.context() as patch:
        for name in ("MemberLinear", "MemberConv2d", "MCDropout"):
            patch.setattr(networks, name, getattr(frozen, name))
        reference = _train(env_id, method)
    assert ours.keys() == reference.keys()
    for key in ours:
        assert th.equal(ours[key], reference[key]), key
