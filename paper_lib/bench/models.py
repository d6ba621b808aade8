"""Build the compared models: every method with the same network sizes and PPO settings.

`make_agent` gives Masksembles the paper's wider layers (384 vs 256 on HalfCheetah); a cost
comparison needs equal sizes, so this mirrors make_agent's construction (same env, wrappers,
policy classes and settings) with the widths taken from the BenchConfig.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecEnv

from paper_lib.agents.envs import is_atari, make_env
from paper_lib.agents.factory import paper_hyperparameters
from paper_lib.bench.config import BenchConfig
from paper_lib.methods.groups import MemberGroupVecEnv, check_member_layout
from paper_lib.methods.policy import MemberActorCriticPolicy


def make_bench_env(config: BenchConfig, env_id: str) -> VecEnv:
    """The vectorized env a model of this benchmark trains in (also the env-stepping ceiling's)."""
    hp = paper_hyperparameters(env_id)
    return make_env(env_id, config.n_envs(env_id), config.seed, normalize_obs=hp["normalize_obs"])


def build_model(config: BenchConfig, env_id: str, method: str, env: VecEnv | None = None) -> PPO:
    """A PPO model for `method` on `env_id`; widths from `config.hidden_sizes` (equal by default)."""
    algo_kwargs: dict[str, Any] = config.algo_kwargs(env_id)
    env = env if env is not None else make_bench_env(config, env_id)
    hidden = config.hidden_sizes(env_id, method)
    if method == "baseline":
        policy: Any = "CnnPolicy" if is_atari(env_id) else "MlpPolicy"
        policy_kwargs: dict[str, Any] = {} if is_atari(env_id) else {"net_arch": {"pi": hidden, "vf": hidden}}
    else:
        check_member_layout(env.num_envs, config.n_members, algo_kwargs["batch_size"], algo_kwargs["n_steps"])
        env = MemberGroupVecEnv(env, config.n_members)
        policy = MemberActorCriticPolicy
        policy_kwargs = dict(method=method, n_members=config.n_members, member_seed=config.seed)
        if not is_atari(env_id):
            policy_kwargs["hidden_sizes"] = tuple(hidden)
    return PPO(policy, env, seed=config.seed, device="cpu", verbose=0, policy_kwargs=policy_kwargs, **algo_kwargs)


def random_actions(env: VecEnv) -> np.ndarray:
    """One random action per sub-env, as VecEnv.step expects them."""
    return np.stack([env.action_space.sample() for _ in range(env.num_envs)])


def has_measures(model: PPO, method: str) -> bool:
    """Whether `uncertainty` applies: member methods always; a baseline for discrete actions only."""
    return method != "baseline" or isinstance(model.action_space, spaces.Discrete)
