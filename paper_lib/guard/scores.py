"""Per-state OOD scores a guard can threshold: member measures, member-free detectors, combinations.

Every score maps a batch of policy observations (what the policy sees, after VecNormalize if
the agent used it) to one number per state, higher = more unusual. A score is calibrated and
deployed with the same function, so calibration and deployment scores are computed alike,
which exchangeability needs (MC masks are drawn per state, so batching does not matter; see
``batch_size_for``).

A score that is fitted on ID states (a detector, the reference of a combination) must never be
calibrated on those same states: a kNN distance is ~0 on its own fit states, which would give
a threshold far too low. Scores remember hashes of the states they were fitted on, and a guard
refuses calibration states that overlap them.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy

from paper_lib.measures.definitions import DISCRETE_ONLY, MEMBER_MEASURES
from paper_lib.measures.detectors import KNNDetector, MahalanobisDetector
from paper_lib.measures.estimates import policy_features, uncertainty
from paper_lib.methods.policy import MemberActorCriticPolicy

DETECTORS = ("mahalanobis", "knn")
DETECTOR_INPUTS = ("obs", "features")
#: Detector score names as notebook 3 spells them: "<detector>_<input>".
DETECTOR_SCORES = tuple(f"{d}_{on}" for d in DETECTORS for on in DETECTOR_INPUTS)
SCORE_NAMES = MEMBER_MEASURES + DISCRETE_ONLY + DETECTOR_SCORES


def policy_of(model: BaseAlgorithm | BasePolicy) -> BasePolicy:
    if isinstance(model, BaseAlgorithm):
        return model.policy
    if isinstance(model, BasePolicy):
        return model
    raise ValueError(f"expected an SB3 model (e.g. PPO.load(...)) or its policy, got {type(model).__name__}.")


def batch_size_for(policy: BasePolicy) -> int:
    """States per forward pass that keep scores exchangeable with deployment (one state per step).

    Policies that draw MC masks per state (``per_state_masks``) score a state alike in any batch.
    A policy that drew MC DropConnect's weight masks once per pass would give a batch correlated
    scores, so it is scored as it is deployed: one state per pass.
    """
    if isinstance(policy, MemberActorCriticPolicy) and policy.member_spec.method == "mc_dropconnect" \
            and not hasattr(policy, "per_state_masks"):
        return 1
    return 1024


def state_hashes(states: np.ndarray) -> set[bytes]:
    """One digest per state (float32 bytes), to find states shared by a fit set and a calibration set."""
    arr = np.ascontiguousarray(np.asarray(states, dtype=np.float32).reshape(len(states), -1))
    return {hashlib.blake2b(row.tobytes(), digest_size=16).digest() for row in arr}


def as_states(states: Any, what: str) -> np.ndarray:
    arr = np.asarray(states)
    if arr.ndim < 2 or arr.shape[0] == 0:
        raise ValueError(f"{what} must be an array of shape (N, *obs_shape) with N >= 1, got shape {arr.shape}; "
                         "for one state use states[None].")
    return arr


@contextmanager
def own_rng(rng: np.random.Generator) -> Iterator[None]:
    """Run MC members on a seed from ``rng``, leaving torch's global RNG as it was.

    The agent's sampled actions draw from torch's global RNG; a guard that drew its MC masks
    from it too would change the agent's actions just by watching them.
    """
    with th.random.fork_rng(devices=[]):
        th.manual_seed(int(rng.integers(2**63 - 1)))
        yield


class Score:
    """Base class: ``name``, ``__call__(policy_obs) -> (N,)``, and what persistence needs."""

    name: str = "score"
    kind: str = "score"
    #: Digests of the ID states this score was fitted on; calibration states must avoid them.
    fit_hashes: frozenset[bytes] = frozenset()

    def __call__(self, policy_obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def spec(self) -> dict[str, Any]:
        """JSON description from which ``load_score`` rebuilds this score for the same model."""
        return {"kind": self.kind, "name": self.name}

    def arrays(self) -> dict[str, np.ndarray]:
        """Arrays the rebuild needs (fit inputs), saved beside the spec."""
        return {}


class MemberScore(Score):
    """One of the paper's member measures (``paper_lib.measures.estimates``): value_std, policy_std, policy_js,
    and for discrete actions max_prob and entropy (the last two also exist for a baseline)."""

    kind = "member"

    def __init__(self, model: BaseAlgorithm | BasePolicy, measure: str, batch_size: int | None = None,
                 seed: int = 0) -> None:
        self.policy = policy_of(model)
        self.rng = np.random.default_rng(seed)  # MC members' masks (see own_rng)
        has_members = isinstance(self.policy, MemberActorCriticPolicy)
        discrete = isinstance(self.policy.action_space, spaces.Discrete)
        available = (MEMBER_MEASURES if has_members else ()) + (DISCRETE_ONLY if discrete else ())
        if measure not in available:
            if measure in MEMBER_MEASURES and not has_members:
                raise ValueError(f"{measure} needs ensemble members, but this policy has none (baseline); use a member "
                                 f"method, or a member-free detector score such as {DETECTOR_SCORES}.")
            raise ValueError(f"score {measure!r} is not available for this policy; available member measures: "
                             f"{available}, detector scores: {DETECTOR_SCORES}.")
        self.name = self.measure = measure
        self.batch_size = batch_size_for(self.policy) if batch_size is None else int(batch_size)

    def __call__(self, policy_obs: np.ndarray) -> np.ndarray:
        states = as_states(policy_obs, "states to score")
        with own_rng(self.rng):
            return uncertainty(self.policy, states, (self.measure,), batch_size=self.batch_size)[self.measure]


class DetectorScore(Score):
    """A member-free detector (``paper_lib.measures.detectors``): Mahalanobis or kNN distance to ID states,
    on the observations or on the policy's last hidden features, fitted on ``fit_states``."""

    kind = "detector"

    def __init__(self, model: BaseAlgorithm | BasePolicy, detector: str, on: str, fit_states: np.ndarray | None,
                 k: int = 5, seed: int = 0, _fit_inputs: np.ndarray | None = None) -> None:
        if detector not in DETECTORS:
            raise ValueError(f"detector={detector!r}: use one of {DETECTORS}.")
        if on not in DETECTOR_INPUTS:
            raise ValueError(f"on={on!r}: a detector reads 'obs' (policy observations) or 'features' (the policy's "
                             "last hidden layer).")
        self.policy = policy_of(model)
        self.detector, self.on, self.k = detector, on, int(k)
        self.rng = np.random.default_rng(seed)  # MC members' masks in the features (see own_rng)
        self.name = f"{detector}_{on}"
        if _fit_inputs is None:  # fresh fit: remember which states it saw
            states = as_states(fit_states, f"fit_states of {self.name}")
            self.fit_hashes = frozenset(state_hashes(states))
            _fit_inputs = self._inputs(states)
        self.fit_inputs = np.asarray(_fit_inputs, dtype=np.float64)
        self.model_ = (MahalanobisDetector() if detector == "mahalanobis" else KNNDetector(self.k)).fit(self.fit_inputs)

    def _inputs(self, policy_obs: np.ndarray) -> np.ndarray:
        if self.on == "obs":
            return np.asarray(policy_obs, dtype=np.float64).reshape(len(policy_obs), -1)
        with own_rng(self.rng):
            return policy_features(self.policy, policy_obs, batch_size=batch_size_for(self.policy))

    def __call__(self, policy_obs: np.ndarray) -> np.ndarray:
        return self.model_.score(self._inputs(as_states(policy_obs, "states to score")))

    def spec(self) -> dict[str, Any]:
        return {"kind": self.kind, "name": self.name, "detector": self.detector, "on": self.on, "k": self.k}

    def arrays(self) -> dict[str, np.ndarray]:
        # The detector's inputs, not the states: features of stochastic members would differ on a refit.
        return {"fit_inputs": self.fit_inputs}


class CallableScore(Score):
    """Any function of a batch of policy observations, e.g. a hand-made combination of measures.

    Functions are not saved: ``Guard.load(..., score=CallableScore(same_fn, same_name))``.
    """

    kind = "callable"

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray], name: str,
                 fit_states: np.ndarray | None = None) -> None:
        if not callable(fn):
            raise ValueError(f"CallableScore needs a function states -> scores, got {type(fn).__name__}.")
        if not isinstance(name, str) or not name.strip():
            raise ValueError("CallableScore needs a non-empty name: it identifies the guard when it is saved and loaded.")
        self.fn, self.name = fn, name
        if fit_states is not None:
            self.fit_hashes = frozenset(state_hashes(as_states(fit_states, "fit_states")))

    def __call__(self, policy_obs: np.ndarray) -> np.ndarray:
        states = as_states(policy_obs, "states to score")
        out = np.asarray(self.fn(states), dtype=float).reshape(-1)
        if out.shape != (len(states),):
            raise ValueError(f"score function {self.name!r} returned {out.size} values for {len(states)} states; "
                             "it must return one score per state.")
        return out


class CombinedScore(Score):
    """Several scores on one scale: each becomes its rank among reference ID scores, then the max (or mean).

    The reference states are ID states held out from calibration (like a detector's fit states):
    the rank transform is fitted on them.
    """

    kind = "combined"

    def __init__(self, components: Sequence[Score], reference_states: np.ndarray | None, how: str = "max",
                 _reference_scores: Mapping[str, np.ndarray] | None = None) -> None:
        if len(components) < 2 or not all(isinstance(c, Score) for c in components):
            raise ValueError("CombinedScore needs at least two Score objects (e.g. MemberScore and DetectorScore).")
        if how not in ("max", "mean"):
            raise ValueError(f"how={how!r}: combine ranks by 'max' or 'mean'.")
        self.components, self.how = list(components), how
        self.name = f"{how}_rank(" + ",".join(c.name for c in self.components) + ")"
        if _reference_scores is None:
            states = as_states(reference_states, "reference_states")
            _reference_scores = {c.name: c(states) for c in self.components}
            self.fit_hashes = frozenset(state_hashes(states)).union(*(c.fit_hashes for c in self.components))
        else:
            self.fit_hashes = frozenset().union(*(c.fit_hashes for c in self.components))
        self.reference = {c.name: np.sort(np.asarray(_reference_scores[c.name], dtype=float)) for c in self.components}

    def __call__(self, policy_obs: np.ndarray) -> np.ndarray:
        states = as_states(policy_obs, "states to score")
        ranks = [np.searchsorted(self.reference[c.name], c(states), side="right") / (len(self.reference[c.name]) + 1)
                 for c in self.components]
        return np.max(ranks, axis=0) if self.how == "max" else np.mean(ranks, axis=0)

    def spec(self) -> dict[str, Any]:
        return {"kind": self.kind, "name": self.name, "how": self.how, "components": [c.spec() for c in self.components]}

    def arrays(self) -> dict[str, np.ndarray]:
        out = {f"reference/{name}": ref for name, ref in self.reference.items()}
        for i, c in enumerate(self.components):
            out.update({f"component{i}/{key}": value for key, value in c.arrays().items()})
        return out


def make_score(model: BaseAlgorithm | BasePolicy, name: str, fit_states: np.ndarray | None = None) -> Score:
    """A score by name: a member measure, or "<mahalanobis|knn>_<obs|features>" fitted on ``fit_states``."""
    if name in DETECTOR_SCORES:
        if fit_states is None:
            raise ValueError(f"{name} is a detector and must be fitted: pass fit_states= ID states held out from the "
                             "calibration states.")
        detector, on = name.split("_", 1)
        return DetectorScore(model, detector, on, fit_states)
    if name in MEMBER_MEASURES + DISCRETE_ONLY:
        return MemberScore(model, name)
    raise ValueError(f"unknown score {name!r}; use one of {SCORE_NAMES}, or wrap your own function in CallableScore.")


def available_scores(model: BaseAlgorithm | BasePolicy) -> list[str]:
    """Score names that apply to this model (member measures only for member policies)."""
    policy = policy_of(model)
    discrete = isinstance(policy.action_space, spaces.Discrete)
    members = list(MEMBER_MEASURES) if isinstance(policy, MemberActorCriticPolicy) else []
    return members + (list(DISCRETE_ONLY) if discrete else []) + list(DETECTOR_SCORES)


def load_score(model: BaseAlgorithm | BasePolicy, spec: Mapping[str, Any], arrays: Mapping[str, np.ndarray],
               prefix: str = "") -> Score:
    """Rebuild a saved score for ``model`` (callables cannot be rebuilt: pass them to ``Guard.load``)."""
    kind = spec.get("kind")
    if kind == "member":
        return MemberScore(model, spec["name"])
    if kind == "detector":
        return DetectorScore(model, spec["detector"], spec["on"], None, k=spec.get("k", 5),
                             _fit_inputs=arrays[f"{prefix}fit_inputs"])
    if kind == "combined":
        parts = [load_score(model, c, arrays, f"{prefix}component{i}/") for i, c in enumerate(spec["components"])]
        refs = {c.name: arrays[f"{prefix}reference/{c.name}"] for c in parts}
        return CombinedScore(parts, None, spec["how"], _reference_scores=refs)
    raise ValueError(f"the saved score {spec.get('name')!r} is a {kind} score, which is not saved with the guard: "
                     "pass the same function again, Guard.load(..., score=CallableScore(fn, name)).")


def score_many(scores: Mapping[str, Score], policy_obs: np.ndarray) -> dict[str, np.ndarray]:
    """Every score on the same states; member measures of one policy come from one shared pass."""
    states = as_states(policy_obs, "states to score")
    out: dict[str, np.ndarray] = {}
    groups: dict[tuple[int, int], dict[str, MemberScore]] = {}
    for key, s in scores.items():
        if isinstance(s, MemberScore):
            groups.setdefault((id(s.policy), s.batch_size), {})[key] = s
        else:
            out[key] = s(states)
    for group in groups.values():
        first = next(iter(group.values()))
        measures = tuple(dict.fromkeys(s.measure for s in group.values()))
        with own_rng(first.rng):
            computed = uncertainty(first.policy, states, measures, batch_size=first.batch_size)
        out.update({key: computed[s.measure] for key, s in group.items()})
    return {key: out[key] for key in scores}
