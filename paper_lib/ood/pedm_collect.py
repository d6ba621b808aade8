"""One run's agent under PEDM's protocol: its ID training episodes and its 5 kinds x 2 severities of test episodes.

`play_pedm_episodes` plays one (kind, severity); this module fixes what a run's collection is, so the `pedm` stage
and the budget measurement (`paper_lib.experiments.pedm_budget`) play the same episodes:

- **ID training episodes:** ``n_id`` unperturbed episodes (PEDM's ``oodd_runner.py`` ``n_train_episodes`` default:
  50), episode seeds from ``1000 * seed + 3``;
- **threshold episodes:** params.yaml's ``pedm.threshold_episodes`` more unperturbed episodes (19: false alarms
  at most 1/20), seeds from ``1000 * seed + 5``, held out of every fit: the ID scores a detection delay's
  threshold is read from;
- **test episodes:** ``n_test`` episodes per (kind, severity) (PEDM: 100; ours 20, docs/deviations.md), episode
  seeds from ``1000 * seed + 4``, the same for every kind and severity (paired kinds: one injection step per episode);
- **actions:** deterministic, as PEDM's TD3 plays; the agent reads the run's frozen VecNormalize view of each
  observation, the detectors the raw one. The run's collect stage uses seeds ``1000 * seed + 1`` and ``+ 2``, so
  none of these episodes is one of its.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch as th

from paper_lib.ood.pedm_protocol import KINDS, SEVERITIES, Agent, play_pedm_episodes

#: PEDM's number of ID episodes the detector fits on (``oodd_runner.py``: ``--n_train_episodes`` default 50).
PEDM_ID_EPISODES = 50
#: Test episodes per (kind, severity): PEDM plays 100 (``--test_episodes``); ours 20 (the issue's budget).
TEST_EPISODES = 20
ID_SEED_OFFSET, TEST_SEED_OFFSET, THRESHOLD_SEED_OFFSET = 3, 4, 5
#: Every (kind, severity) of the protocol, in the order a collection holds them.
CONDITIONS = tuple((kind, severity) for severity in SEVERITIES for kind in KINDS)


@dataclass(frozen=True)
class LoadedAgent:
    """A run's agent and the map from raw observations to what its policy reads (None: raw)."""

    model: Agent
    policy_obs: Callable[[np.ndarray], np.ndarray] | None


def play_id(agent: LoadedAgent, env_id: str, seed: int, n_episodes: int = PEDM_ID_EPISODES,
            max_steps: int | None = None, offset: int = ID_SEED_OFFSET) -> dict[str, np.ndarray]:
    """The run's unperturbed ID episodes (``kind=None``), deterministic actions: training ones by default, the
    threshold ones with ``offset=THRESHOLD_SEED_OFFSET``."""
    th.manual_seed(1000 * seed + offset)  # an MC method's members draw from torch
    return play_pedm_episodes(agent.model, env_id, None, n_episodes=n_episodes, seed=1000 * seed + offset,
                              policy_obs=agent.policy_obs, max_steps=max_steps)


def play_tests(agent: LoadedAgent, env_id: str, seed: int, n_episodes: int = TEST_EPISODES,
               max_steps: int | None = None, injection_step: int | None = None,
               conditions: tuple[tuple[str, str], ...] = CONDITIONS) -> dict[tuple[str, str], dict[str, np.ndarray]]:
    """The run's test episodes of each (kind, severity) of ``conditions``, each collection played from the same seeds."""
    out = {}
    for kind, severity in conditions:
        th.manual_seed(1000 * seed + TEST_SEED_OFFSET)
        out[(kind, severity)] = play_pedm_episodes(
            agent.model, env_id, kind, severity, n_episodes=n_episodes, seed=1000 * seed + TEST_SEED_OFFSET,
            policy_obs=agent.policy_obs, max_steps=max_steps, injection_step=injection_step)
    return out
