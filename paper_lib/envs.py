"""Environment ids and vectorized env factories (MuJoCo v5, Atari with SB3's wrappers)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from stable_baselines3.common.env_util import make_atari_env, make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecFrameStack, VecNormalize

MUJOCO_ENVS = ("HalfCheetah-v5", "Ant-v5", "Walker2d-v5", "Swimmer-v5")
ATARI_ENVS = ("SeaquestNoFrameskip-v4", "MsPacmanNoFrameskip-v4", "BerzerkNoFrameskip-v4", "SpaceInvadersNoFrameskip-v4")
N_STACK = 4


def is_atari(env_id: str) -> bool:
    return env_id.endswith("NoFrameskip-v4")


def register_atari() -> None:
    """ale-py ships the ROMs but gymnasium only knows its ids after registration."""
    import ale_py

    gym.register_envs(ale_py)


def make_env(env_id: str, n_envs: int, seed: int, normalize_obs: bool = False,
             env_kwargs: dict[str, Any] | None = None) -> VecEnv:
    """The vectorized env an agent trains in: Atari gets AtariWrapper + 4 stacked frames."""
    if is_atari(env_id):
        register_atari()
        venv: VecEnv = VecFrameStack(make_atari_env(env_id, n_envs, seed=seed, vec_env_cls=DummyVecEnv,
                                                    env_kwargs=env_kwargs), N_STACK)
    else:
        venv = make_vec_env(env_id, n_envs, seed=seed, vec_env_cls=DummyVecEnv, env_kwargs=env_kwargs)
    if normalize_obs:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    return venv
