"""The calibrated OOD guard: a conformal threshold on a per-state score, per state or per episode.

``Guard(model, score, calibration_states, alpha)`` flags a state whose score exceeds the
conformal threshold of held-out ID states. **Assumption:** the calibration states and the state
being tested are exchangeable (e.g. i.i.d. draws of "a state at a uniformly random step of a
fresh ID episode", one per held-out episode). Then the probability that an ID state is flagged
is at most alpha. States of one episode are correlated, so every state of a few episodes is not
such a sample, and a per-state guard raises about alpha x T alarms in an ID episode of T steps.

``SequentialGuard(model, score, calibration_episodes, alpha, WindowMean(w) | Cusum(drift))``
smooths the scores along the episode and calibrates the per-episode maximum of that statistic
on whole held-out ID episodes. **Assumption:** the calibration episodes and the test episode are
exchangeable (same env, policy, action mode and episode length, independent seeds). Then the
probability that an ID episode raises any alarm is at most alpha; the unit is the episode.

Both bounds are marginal: on average over the draw of the calibration set. For one calibration set
the realized rate is itself random (Beta(n+1-k, k) for continuous scores, k = ceil((n+1)(1-alpha))),
so a small n scatters widely around alpha. ``confidence=0.9`` raises k so that, with probability
>= 0.9 over the calibration set, this guard's own rate is <= alpha (needs more units: 45 for alpha 0.05). Neither guarantee says anything about OOD states
(detection power is measured, not promised), nor survives calibrating on states the score was
fitted on (refused here) or deploying with a different action mode, episode length or observation
normalization than in calibration.
"""

from __future__ import annotations

import hashlib
import json
import re
import warnings
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy

from paper_lib.guard.conformal import (
    check_alpha,
    check_calibration_size,
    check_confidence,
    check_episodes,
    conformal_threshold,
    episode_maximum,
    false_alarm_bound,
)
from paper_lib.common.io import (atomic_dir, check_folder_destination, check_replaceable_dir, save_npz_atomic,
                                 write_json_atomic)
from paper_lib.common.provenance import package_versions
from paper_lib.guard.scores import Score, as_states, load_score, make_score, policy_of, state_hashes
from paper_lib.guard.sequential import Cusum, Statistic, WindowMean, statistic_from_dict

FORMAT = "paper_lib.Guard/1"
GUARDS_DIR = "guards"
#: A sequential guard's statistic unless told otherwise.
DEFAULT_STATISTIC = WindowMean(10)
#: Package versions of this process (read once: importlib.metadata is slow).
_versions = cache(package_versions)


# ------------------------------------------------------------------------------ model identity


def model_fingerprint(model: BaseAlgorithm | BasePolicy) -> str:
    """SHA-256 of the policy's weights and buffers (Masksembles masks included).

    The inference-mode buffers are left out: switching vote/average/single changes how
    actions combine, not what the members output.
    """
    digest = hashlib.sha256()
    for name, tensor in sorted(policy_of(model).state_dict().items()):
        if name.rsplit(".", 1)[-1].startswith("_inference"):
            continue
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


def model_identity(model: BaseAlgorithm | BasePolicy) -> dict[str, Any]:
    config = getattr(model, "paper_lib_config", None) or {}
    return {"fingerprint": model_fingerprint(model), "class": type(model).__name__,
            "policy": type(policy_of(model)).__name__,
            **{key: config.get(key) for key in ("algo", "method", "env_id", "seed")}}


def _describe(identity: dict[str, Any]) -> str:
    what = " ".join(str(identity[k]) for k in ("method", "env_id") if identity.get(k) is not None)
    seed = f", seed {identity['seed']}" if identity.get("seed") is not None else ""
    return f"a {identity.get('class')} {what or identity.get('policy')}{seed} (weights {identity['fingerprint'][:12]})"


def describe_model(model: BaseAlgorithm | BasePolicy) -> str:
    """A model as error messages name it: class, method, env, seed and the start of its weights' hash."""
    return _describe(model_identity(model))


def needs_normalization(model: BaseAlgorithm | BasePolicy) -> bool:
    """Whether the agent acts on VecNormalize-d observations (its scores must be computed on those)."""
    config = getattr(model, "paper_lib_config", None) or {}
    normalizer = model.get_vec_normalize_env() if isinstance(model, BaseAlgorithm) else None
    return bool(config.get("normalize_obs")) or normalizer is not None


# ---------------------------------------------------------------------------------- readings


@dataclass
class Reading:
    """One step of a monitored batch of envs: each env's score, statistic, flag and alarm onset."""

    scores: np.ndarray
    statistics: np.ndarray
    flags: np.ndarray
    onsets: np.ndarray  # flagged now but not at the previous step of the same episode



#: What guard.json must hold for `Guard.load` (`Guard.save` writes them all).
META_KEYS = ("format", "model", "score", "unit", "alpha", "statistic", "threshold", "versions")


def _damaged(path: Path, why: str) -> ValueError:
    return ValueError(f"{path} {why}: the saved guard is damaged or incomplete; calibrate it again and save it with "
                      "guard.save(folder) (nothing was loaded)")


def _read_meta(path: Path) -> dict:
    """guard.json as a dict with every key `Guard.load` reads, or one error naming the file and the fix."""
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise _damaged(path, f"is not readable JSON ({type(err).__name__}: {err})") from None
    if not isinstance(meta, dict):
        raise _damaged(path, f"holds a {type(meta).__name__}, not a JSON object")
    missing = [key for key in META_KEYS if key not in meta]
    if missing:
        raise _damaged(path, f"lacks {missing}")
    return meta


def _read_arrays(path: Path, required: tuple[str, ...]) -> dict[str, np.ndarray]:
    """arrays.npz whole, or one error naming the file and the fix (a cut or missing file, a missing array)."""
    try:
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as err:  # a missing file, zipfile.BadZipFile, a cut member (EOFError, ValueError): causes vary
        raise _damaged(path, f"is not a readable .npz ({type(err).__name__}: {err})") from None
    missing = [key for key in required if key not in arrays]
    if missing:
        raise _damaged(path, f"lacks the arrays {missing}")
    return arrays

class GuardMonitor:
    """A guard applied online to ``n_envs`` parallel episodes; ``reset(mask)`` at each episode start."""

    def __init__(self, guard: Guard, n_envs: int = 1) -> None:
        if isinstance(n_envs, bool) or not isinstance(n_envs, (int, np.integer)) or n_envs < 1:
            raise ValueError(f"n_envs={n_envs!r}: monitor at least one env.")
        self.guard, self.n_envs = guard, int(n_envs)
        self._online = guard.statistic.online(self.n_envs) if guard.statistic is not None else None
        self._flagged = np.zeros(self.n_envs, dtype=bool)

    def reset(self, mask: np.ndarray | None = None) -> None:
        """Start new episodes where ``mask`` is True (all envs if None): the statistic forgets them."""
        mask = np.ones(self.n_envs, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).reshape(-1)
        if mask.shape != (self.n_envs,):
            raise ValueError(f"reset mask has {mask.size} entries for {self.n_envs} envs; give one per env.")
        if self._online is not None:
            self._online.reset(mask)
        self._flagged[mask] = False

    def step(self, policy_obs: np.ndarray) -> Reading:
        """Score one observation per env (what the policy sees) and update every statistic."""
        scores = self.guard.score(policy_obs)
        if scores.shape != (self.n_envs,):
            raise ValueError(f"got {scores.size} observations for a monitor of {self.n_envs} envs; pass one per env.")
        stats = self._online.update(scores) if self._online is not None else scores.astype(float)
        flags = stats > self.guard.threshold
        onsets = flags & ~self._flagged
        self._flagged = flags.copy()
        return Reading(scores, stats, flags, onsets)


# ------------------------------------------------------------------------------------- guards


def _key(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "score"


class Guard:
    """A per-state guard: flags a state whose score exceeds the split-conformal threshold.

    ``score`` is a ``Score`` (``MemberScore``, ``DetectorScore``, ``CallableScore``,
    ``CombinedScore``) or a member measure's name; ``calibration_states`` are policy
    observations (N, *obs_shape) of ID states held out from training and from the score's fit.
    """

    unit = "state"

    def __init__(self, model: BaseAlgorithm | BasePolicy, score: Score | str, calibration_states: np.ndarray,
                 alpha: float, confidence: float | None = None) -> None:
        self._setup(model, score, alpha, None, confidence)
        states = as_states(calibration_states, "calibration_states")
        check_calibration_size(len(states), self.alpha, "calibration states", self.confidence)
        self._check_held_out(states)
        self._calibrate(self.score(states))

    @classmethod
    def from_scores(cls, model: BaseAlgorithm | BasePolicy, score: Score | str, calibration_scores: np.ndarray,
                    alpha: float, confidence: float | None = None) -> Guard:
        """A guard from scores already computed with ``score`` on held-out ID states (one per unit)."""
        guard = cls.__new__(cls)
        guard._setup(model, score, alpha, None, confidence)
        guard._calibrate(calibration_scores)
        return guard

    # --- construction -------------------------------------------------------------------
    def _setup(self, model: BaseAlgorithm | BasePolicy, score: Score | str, alpha: float,
               statistic: Statistic | None, confidence: float | None = None) -> None:
        self.model = model
        policy_of(model)  # a clear error for anything that is not an SB3 model or policy
        self.alpha = check_alpha(alpha)
        self.confidence = check_confidence(confidence)
        if isinstance(score, str):
            score = make_score(model, score)
        if not isinstance(score, Score):
            raise ValueError(f"score must be a Score (MemberScore, DetectorScore, CallableScore, CombinedScore) or a "
                             f"member measure's name, got {type(score).__name__}; wrap a function in "
                             "CallableScore(fn, name).")
        self.score = score
        self.statistic = statistic
        self.versions = dict(_versions())

    def _check_held_out(self, states: np.ndarray) -> None:
        if not self.score.fit_hashes:
            return
        shared = len(state_hashes(states) & self.score.fit_hashes)
        if shared:
            raise ValueError(f"{shared} of the {len(states)} calibration states were used to fit the score "
                             f"{self.score.name!r}; its scores there are too low and the threshold would be wrong. "
                             "Calibrate on ID states held out from the fit (e.g. paper_lib.measures.detectors.split_fit_eval).")

    def _calibrate(self, calibration_scores: np.ndarray) -> None:
        scores = np.asarray(calibration_scores, dtype=float).reshape(-1)
        self.threshold = conformal_threshold(scores, self.alpha, f"calibration {self.unit}s", self.confidence)
        self.calibration_scores = scores

    # --- use ----------------------------------------------------------------------------
    @property
    def n_calibration(self) -> int:
        return int(self.calibration_scores.size)

    @property
    def expected_false_alarm_rate(self) -> float:
        """(n + 1 - k) / (n + 1): the false-alarm rate expected over calibration sets, for tie-free scores (<= alpha)."""
        return false_alarm_bound(self.n_calibration, self.alpha, self.confidence)

    @property
    def name(self) -> str:
        return self.score.name

    @property
    def key(self) -> str:
        """The guard's folder name: score name and statistic."""
        return _key(f"{self.score.name}-{self.statistic.label if self.statistic is not None else 'state'}")

    def statistic_path(self, scores: np.ndarray) -> np.ndarray:
        """The flagged quantity along an episode's per-step scores (per state: the scores themselves)."""
        return np.asarray(scores, dtype=float).reshape(-1)

    def alarms(self, episode_scores: np.ndarray) -> np.ndarray:
        """Flags along one episode's per-step scores: statistic > threshold."""
        return self.statistic_path(episode_scores) > self.threshold

    def flags(self, policy_obs: np.ndarray) -> np.ndarray:
        """Per-state flags for a batch of independent states (per-state guards only)."""
        if self.statistic is not None:
            raise ValueError("a sequential guard flags episodes step by step: use monitor() or alarms(episode_scores).")
        return self.score(policy_obs) > self.threshold

    def monitor(self, n_envs: int = 1) -> GuardMonitor:
        return GuardMonitor(self, n_envs)

    def _certainty(self) -> str:
        """How the bound holds: on average over calibration sets, or for this set with a stated probability."""
        if self.confidence is None:
            return ""
        return f", for this calibration set with probability >= {self.confidence:g}"

    def guarantee(self) -> str:
        return (f"P(an ID state is flagged) <= alpha = {self.alpha:g} for states exchangeable with the {self.n_calibration} "
                f"calibration states{self._certainty()}")

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(score={self.score.name!r}, alpha={self.alpha:g}, "
                + (f"confidence={self.confidence:g}, " if self.confidence is not None else "") + f"n={self.n_calibration}, "
                f"threshold={self.threshold:.6g}" + (f", {self.statistic}" if self.statistic is not None else "") + ")")

    # --- persistence --------------------------------------------------------------------
    def save(self, folder: str | Path) -> Path:
        """Write ``folder/guards/<key>/`` (guard.json + arrays.npz) in one atomic swap; returns that path.

        ``folder`` is a folder (made if missing); a file there, or anywhere on the way, is a ValueError
        (``DestinationError``) before anything is written.
        """
        check_folder_destination(folder, "Guard.save: folder")
        target = check_replaceable_dir(Path(folder) / GUARDS_DIR / self.key, "Guard.save: guard folder")
        meta = {"format": FORMAT, "unit": self.unit, "alpha": self.alpha, "confidence": self.confidence,
                "threshold": self.threshold,
                "n_calibration": self.n_calibration, "score": self.score.spec(),
                "statistic": self.statistic.to_dict() if self.statistic is not None else None,
                "model": model_identity(self.model), "normalize_obs": needs_normalization(self.model),
                "versions": self.versions, "guarantee": self.guarantee()}
        with atomic_dir(target) as tmp:
            save_npz_atomic(tmp / "arrays.npz", calibration_scores=self.calibration_scores,
                            **{f"score/{k}": v for k, v in self.score.arrays().items()})
            write_json_atomic(tmp / "guard.json", meta)
        return target

    @staticmethod
    def load(folder: str | Path, model: BaseAlgorithm | BasePolicy, key: str | None = None,
             score: Score | str | None = None) -> Guard:
        """The guard saved under ``folder/guards/`` for this ``model`` (``key`` picks one of several).

        ``score`` is needed only for a ``CallableScore`` (functions are not saved); a name or a
        score that differs from the saved one, or a model with other weights, is a ValueError.
        """
        root = Path(folder) / GUARDS_DIR
        available = sorted(p.name for p in root.iterdir() if (p / "guard.json").is_file()) if root.is_dir() else []
        if key is None:
            if len(available) != 1:
                what = f"several guards {available}: pass key= one of them" if available else "no guard"
                raise FileNotFoundError(f"{root} holds {what}" + ("" if available else "; save one with guard.save(folder)"))
            key = available[0]
        if key not in available:
            raise FileNotFoundError(f"no guard {key!r} in {root} (available: {available}); save it with guard.save(folder)")
        path = root / key
        meta = _read_meta(path / "guard.json")
        if meta.get("format") != FORMAT:
            raise ValueError(f"{path / 'guard.json'} has format {meta.get('format')!r}, not {FORMAT!r}; save the guard again.")
        identity = model_identity(model)
        if meta["model"]["fingerprint"] != identity["fingerprint"]:
            raise ValueError(f"the guard in {path} was calibrated for {_describe(meta['model'])}, but the model given is "
                             f"{_describe(identity)}; its scores would not match the calibration. Load it with the model "
                             "it was saved with, or calibrate a new guard for this model.")
        saved_name = meta["score"]["name"]
        asked = score if isinstance(score, str) else score.name if isinstance(score, Score) else None
        if asked is not None and asked != saved_name:
            raise ValueError(f"the guard in {path} was calibrated for the score {saved_name!r}, not {asked!r}; load it "
                             f"with score={saved_name!r} (or None), or calibrate a new guard for {asked!r}.")
        arrays = _read_arrays(path / "arrays.npz", ("calibration_scores",))
        prefix = "score/"
        rebuilt = score if isinstance(score, Score) else load_score(
            model, meta["score"], {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)})
        cls = SequentialGuard if meta["unit"] == "episode" else Guard
        guard = cls.__new__(cls)
        guard._setup(model, rebuilt, meta["alpha"], statistic_from_dict(meta["statistic"]), meta.get("confidence"))
        guard._calibrate(arrays["calibration_scores"])
        if guard.threshold != meta["threshold"]:
            raise ValueError(f"{path}: the saved threshold {meta['threshold']} does not follow from the saved calibration "
                             f"scores ({guard.threshold}); the folder is damaged, save the guard again.")
        current, guard.versions = guard.versions, meta["versions"]
        changed = {k: (v, current.get(k)) for k, v in meta["versions"].items() if current.get(k) != v}
        if changed:
            warnings.warn(f"guard {path} was saved with other package versions {changed}; scores may differ slightly, "
                          "recalibrate if its false-alarm rate matters.", UserWarning, stacklevel=2)
        return guard


class SequentialGuard(Guard):
    """An episode guard: a sequential statistic of the scores, calibrated on whole held-out ID episodes.

    ``calibration_episodes`` is a list with one array of policy observations (T_i, *obs_shape)
    per ID episode, held out from training and from the score's fit, run like the deployment
    episodes. The calibration score of an episode is the maximum of its statistic.
    """

    unit = "episode"

    def __init__(self, model: BaseAlgorithm | BasePolicy, score: Score | str, calibration_episodes: list[np.ndarray],
                 alpha: float, statistic: Statistic = DEFAULT_STATISTIC, confidence: float | None = None) -> None:
        self._setup(model, score, alpha, _check_statistic(statistic), confidence)
        if isinstance(calibration_episodes, np.ndarray) and calibration_episodes.ndim >= 2 and \
                calibration_episodes.dtype != object:
            raise ValueError("calibration_episodes must be a list with one (T_i, *obs_shape) array per whole episode, "
                             "not one array of states.")
        episodes = [as_states(e, f"calibration episode {i}") for i, e in enumerate(calibration_episodes)]
        check_calibration_size(len(episodes), self.alpha, "calibration episodes", self.confidence)
        self._check_held_out(np.concatenate(episodes))
        self._calibrate_episodes([self.score(e) for e in episodes])

    @classmethod
    def from_episode_scores(cls, model: BaseAlgorithm | BasePolicy, score: Score | str,
                            episode_scores: list[np.ndarray], alpha: float,
                            statistic: Statistic = DEFAULT_STATISTIC,
                            confidence: float | None = None) -> SequentialGuard:
        """A guard from per-step scores already computed with ``score`` on whole held-out ID episodes."""
        guard = cls.__new__(cls)
        guard._setup(model, score, alpha, _check_statistic(statistic), confidence)
        guard._calibrate_episodes(episode_scores)
        return guard

    def _calibrate_episodes(self, episode_scores: list[np.ndarray]) -> None:
        episodes = check_episodes(episode_scores)
        check_calibration_size(len(episodes), self.alpha, "calibration episodes", self.confidence)
        self._calibrate(np.array([episode_maximum(self.statistic.path(e)) for e in episodes]))

    def statistic_path(self, scores: np.ndarray) -> np.ndarray:
        return self.statistic.path(scores)

    def guarantee(self) -> str:
        return (f"P(an ID episode raises any alarm) <= alpha = {self.alpha:g} for episodes exchangeable with the "
                f"{self.n_calibration} calibration episodes ({self.statistic.label} statistic){self._certainty()}")


def _check_statistic(statistic: Any) -> Statistic:
    if not isinstance(statistic, (WindowMean, Cusum)):
        raise ValueError(f"statistic must be WindowMean(window) or Cusum(drift), got {statistic!r}.")
    return statistic
