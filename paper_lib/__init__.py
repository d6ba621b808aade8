"""paper_lib: uncertainty estimation for PPO (and A2C, TRPO) as drop-in SB3 policies.

    from paper_lib import make_agent, uncertainty
    model = make_agent("ppo", "masksembles", "HalfCheetah-v5", seed=0)
    model.learn(1_000_000)
    u = uncertainty(model.policy, observations)   # value_std, policy_std, policy_js, ...

These are the names a user of the paper's methods needs; everything else lives in its layer's package
(docs/layout.md): e.g. `paper_lib.methods` (the policies, env groups, independent ensembles),
`paper_lib.ood` (the OOD generators), `paper_lib.guard` (the calibrated OOD guard).
"""

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what type checkers and editors see; at run time each name is imported on first use (below)
    from paper_lib.agents.checkpoints import load_checkpoint
    from paper_lib.agents.envs import make_env
    from paper_lib.agents.factory import make_agent, paper_hyperparameters
    from paper_lib.guard import Guard, GuardedPolicy
    from paper_lib.measures.definitions import MEMBER_MEASURES
    from paper_lib.measures.estimates import MemberOutputs, act_with_uncertainty, member_outputs, uncertainty
    from paper_lib.methods.networks import MEMBER_METHODS, METHODS
    from paper_lib.pipeline.evaluate_agent import evaluate_agent

__all__ = [
    "make_agent", "paper_hyperparameters", "make_env", "load_checkpoint",
    "METHODS", "MEMBER_METHODS", "MEMBER_MEASURES",
    "uncertainty", "member_outputs", "MemberOutputs", "act_with_uncertainty",
    "evaluate_agent", "Guard", "GuardedPolicy",
]

#: Where each name lives, imported on first use: torch and SB3 take about 2 s to import, which every command under
#: `paper_lib` (a DVC stage's CLI, the notebook runner) would pay through this package's import even where it needs
#: neither; the guard also brings scikit-learn, and evaluate_agent the OOD benchmark.
_HOMES = {
    "load_checkpoint": "paper_lib.agents.checkpoints", "make_env": "paper_lib.agents.envs",
    "make_agent": "paper_lib.agents.factory", "paper_hyperparameters": "paper_lib.agents.factory",
    "MEMBER_MEASURES": "paper_lib.measures.definitions", "MemberOutputs": "paper_lib.measures.estimates",
    "act_with_uncertainty": "paper_lib.measures.estimates", "member_outputs": "paper_lib.measures.estimates",
    "uncertainty": "paper_lib.measures.estimates", "METHODS": "paper_lib.methods.networks",
    "MEMBER_METHODS": "paper_lib.methods.networks", "Guard": "paper_lib.guard", "GuardedPolicy": "paper_lib.guard",
    "evaluate_agent": "paper_lib.pipeline.evaluate_agent",
}


def __getattr__(name: str):
    if name in _HOMES:
        import importlib

        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'paper_lib' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
