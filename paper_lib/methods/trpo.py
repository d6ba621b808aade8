"""TRPO for policies that draw random masks in training (MC Dropout, MC DropConnect).

TRPO's policy step compares the policy with itself: the KL to the old policy, its Hessian (the
Fisher matrix) and the line search's KL all assume that the same parameters give the same
distribution. A network that draws fresh masks at every forward pass breaks that: the KL at
unchanged parameters is no longer zero, its Hessian is not positive semi-definite, and
sb3-contrib's step size sqrt(2 delta / s'Hs) turns NaN, which ends the run at the next forward
pass (half of the study's first MC Dropout TRPO trials did). Here every forward pass of one
policy step draws the same masks: one mask set per update, as one PPO minibatch pass draws one.
Policies without random layers (baseline, Masksembles, Ensemble) train exactly as under
sb3-contrib's TRPO, number for number.
"""

from __future__ import annotations

from collections.abc import Callable

import torch as th
from sb3_contrib import TRPO
from stable_baselines3.common.distributions import Distribution

from paper_lib.methods.layers import has_stochastic_layers

#: Upper bound of the per-update mask seed, drawn from torch's global RNG (so a run's seed fixes it).
_SEED_BOUND = 2**62


class MaskConsistentTRPO(TRPO):
    """sb3-contrib's TRPO whose policy step sees one set of random masks per update."""

    def train(self) -> None:
        if not has_stochastic_layers(self.policy):
            super().train()
            return
        seed = int(th.randint(0, _SEED_BOUND, ()))
        self.policy.get_distribution = _with_fixed_masks(self.policy.get_distribution, seed, self.device)
        try:
            super().train()
        finally:
            del self.policy.get_distribution  # back to the class's method


def _with_fixed_masks(get_distribution: Callable[[th.Tensor], Distribution], seed: int,
                      device: th.device) -> Callable[[th.Tensor], Distribution]:
    """`get_distribution` replaying torch's RNG from `seed` at every call, then restoring it.

    The masks are drawn from torch's global RNG, so the same seed and the same batch shape give
    the same masks; the RNG state outside the call is left as it was, so the critic update and
    the next rollout draw exactly what they would have drawn.
    """

    def same_masks(obs: th.Tensor) -> Distribution:
        with th.random.fork_rng(devices=[device] if device.type == "cuda" else []):
            th.manual_seed(seed)
            return get_distribution(obs)

    return same_masks
