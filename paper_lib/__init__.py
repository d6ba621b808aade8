"""paper_lib: uncertainty estimation for PPO (and A2C, TRPO) as drop-in SB3 policies.

    from paper_lib import make_agent, uncertainty
    model = make_agent("ppo", "masksembles", "HalfCheetah-v5", seed=0)
    model.learn(1_000_000)
    u = uncertainty(model.policy, observations)   # value_std, policy_std, policy_js, ...
"""

from paper_lib.agents.envs import ATARI_ENVS, MUJOCO_ENVS, make_env
from paper_lib.agents.factory import ALGORITHMS, ASSIGNMENTS, make_agent, paper_hyperparameters
from paper_lib.measures.estimates import MemberOutputs, act_with_uncertainty, member_outputs, uncertainty
from paper_lib.methods.buffer import MemberOrderedRolloutBuffer
from paper_lib.methods.groups import MemberGroupVecEnv
from paper_lib.methods.independent import IndependentEnsemblePolicy, assemble_ensemble, load_independent_ensemble
from paper_lib.methods.networks import MEMBER_METHODS, METHODS
from paper_lib.methods.policy import INFERENCE_MODES, MemberActorCriticPolicy

__all__ = [
    "ALGORITHMS", "ASSIGNMENTS", "ATARI_ENVS", "INFERENCE_MODES", "MEMBER_METHODS", "METHODS", "MUJOCO_ENVS",
    "MemberActorCriticPolicy", "MemberGroupVecEnv", "MemberOrderedRolloutBuffer", "MemberOutputs", "act_with_uncertainty", "make_agent",
    "make_env", "member_outputs", "paper_hyperparameters", "uncertainty",
    "IndependentEnsemblePolicy", "assemble_ensemble", "load_independent_ensemble",
    "Cusum", "Guard", "GuardWrapper", "GuardedPolicy", "SequentialGuard", "WindowMean", "make_score",
]

#: The OOD guard's names, served from paper_lib.guard on first use: it imports scikit-learn,
#: which a plain `import paper_lib` should not pay for.
_GUARD_NAMES = ("Cusum", "Guard", "GuardWrapper", "GuardedPolicy", "SequentialGuard", "WindowMean", "make_score")


def __getattr__(name: str):
    if name in _GUARD_NAMES:
        from paper_lib import guard

        return getattr(guard, name)
    raise AttributeError(f"module 'paper_lib' has no attribute {name!r}")
