"""The env-group arithmetic, in one place: n_envs parallel envs form k equal groups and
member g acts in group g (paper appendix A and Fig. "shared buffer")."""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

#: Attribute carried by a terminal observation (and the tensor made from it) naming the
#: member whose env group produced it.
MEMBER_TAG = "paper_lib_member"
#: Attribute carried beside MEMBER_TAG: the number of member groups the envs were split into, so a
#: policy with another k can refuse the tag instead of bootstrapping from the wrong member.
GROUPS_TAG = "paper_lib_member_groups"


def check_member_layout(n_envs: int, n_members: int, batch_size: int | None = None, n_steps: int | None = None) -> None:
    """Raise one clear error when the envs or minibatches cannot be split evenly over members.

    A batch_size of at least the rollout (n_steps*n_envs) means one minibatch of the whole rollout, as SB3's
    RolloutBuffer makes it for the baseline; it splits evenly because the envs do (Walker2d's 4 envs with a
    sampled n_steps 64 and batch_size 512)."""
    for name, value in (("n_envs", n_envs), ("n_members", n_members), ("batch_size", batch_size), ("n_steps", n_steps)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))):
            raise ValueError(f"{name}={value!r} must be an integer")
    if n_members < 2:
        raise ValueError(f"n_members={n_members}: member methods need k >= 2")
    if n_envs < n_members:
        raise ValueError(f"n_envs={n_envs} is fewer than n_members={n_members}; each member needs its own env group: "
                         f"use a positive multiple of {n_members}, e.g. n_envs={2 * n_members}")
    if batch_size is not None and batch_size < 1 or n_steps is not None and n_steps < 1:
        raise ValueError(f"batch_size={batch_size} and n_steps={n_steps} must be positive integers")
    if n_envs % n_members:
        raise ValueError(f"n_envs={n_envs} is not a multiple of n_members={n_members}; each member needs an equal env group")
    if batch_size is not None and not (n_steps is not None and batch_size >= n_steps * n_envs):
        if batch_size % n_members:
            raise ValueError(f"batch_size={batch_size} is not a multiple of n_members={n_members}; "
                             "every minibatch is split into k equal chunks")
        if n_steps is not None and (n_steps * n_envs) % batch_size:
            raise ValueError(f"n_steps*n_envs={n_steps * n_envs} is not a multiple of batch_size={batch_size}; "
                             "the last minibatch would not split evenly over members")


def member_of_env(env_index: int | np.ndarray, n_envs: int, n_members: int):
    """Member acting in env `env_index`: consecutive blocks of n_envs/k envs per member."""
    return env_index // (n_envs // n_members)


class TaggedObservation(np.ndarray):
    """An observation that remembers which member's env group it came from."""

    def __array_finalize__(self, obj) -> None:
        setattr(self, MEMBER_TAG, getattr(obj, MEMBER_TAG, None))
        setattr(self, GROUPS_TAG, getattr(obj, GROUPS_TAG, None))


def tag_observation(obs: np.ndarray, member: int, n_groups: int | None = None) -> TaggedObservation:
    """`obs` tagged with its member (and, from MemberGroupVecEnv, how many groups the envs form)."""
    tagged = np.asarray(obs).view(TaggedObservation)
    setattr(tagged, MEMBER_TAG, int(member))
    setattr(tagged, GROUPS_TAG, None if n_groups is None else int(n_groups))
    return tagged


def member_groups(venv: VecEnv) -> int | None:
    """k of the outermost MemberGroupVecEnv in `venv`'s wrapper chain, or None if there is none."""
    while isinstance(venv, VecEnvWrapper):
        if isinstance(venv, MemberGroupVecEnv):
            return venv.n_members
        venv = venv.venv
    return None


def check_groups_match(venv: VecEnv, n_members: int) -> None:
    """Refuse an env already split into member groups for another k: its truncated episodes would
    bootstrap from the wrong members, silently."""
    groups = member_groups(venv)
    if groups is not None and groups != n_members:
        raise ValueError(f"the given env is a MemberGroupVecEnv for {groups} members, got n_members={n_members}; "
                         f"pass the unwrapped env (make_agent wraps it for k={n_members}) or "
                         f"MemberGroupVecEnv(venv, {n_members})")


class MemberGroupVecEnv(VecEnvWrapper):
    """Tags each terminal observation with its env's member.

    SB3 bootstraps a time-limit-truncated episode with `policy.predict_values` on that one
    env's terminal observation; the tag lets the policy answer with that env's member instead
    of crashing on a batch of one or silently averaging members.
    """

    def __init__(self, venv: VecEnv, n_members: int):
        check_member_layout(venv.num_envs, n_members)
        super().__init__(venv)
        self.n_members = n_members

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        for idx, info in enumerate(infos):
            if info.get("terminal_observation") is not None:
                member = member_of_env(idx, self.num_envs, self.n_members)
                info["terminal_observation"] = tag_observation(info["terminal_observation"], member, self.n_members)
        return obs, rewards, dones, infos
