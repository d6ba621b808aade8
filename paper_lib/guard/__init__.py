"""A calibrated OOD guard for deployed agents (beyond the paper).

    from paper_lib.guard import Guard, SequentialGuard, WindowMean, GuardedPolicy, GuardWrapper, make_score
    score = make_score(model, "mahalanobis_obs", fit_states=fit_obs)        # or "value_std", a CallableScore ...
    guard = SequentialGuard(model, score, calibration_episodes, alpha=0.05, statistic=WindowMean(10))
    evaluate_policy(GuardedPolicy(model, guard, fallback="zero"), env)      # zero action while flagged
    guard.save(folder); Guard.load(folder, model)

Modules: ``conformal`` (thresholds, pure numpy), ``sequential`` (window mean, CUSUM), ``scores``
(member measures, detectors, combinations), ``core`` (the guards, persistence), ``wrappers``
(env and policy wrappers), ``shift`` (mid-episode physics changes), ``settings``, ``experiment``
and ``report`` (notebook 8).
"""

from paper_lib.guard.conformal import conformal_threshold, min_calibration_size
from paper_lib.guard.core import Guard, GuardMonitor, SequentialGuard, model_fingerprint
from paper_lib.guard.scores import CallableScore, CombinedScore, DetectorScore, MemberScore, Score, make_score
from paper_lib.guard.sequential import Cusum, WindowMean
from paper_lib.guard.shift import MidEpisodeShift
from paper_lib.guard.wrappers import Alarm, GuardedPolicy, GuardWrapper

__all__ = [
    "Alarm", "CallableScore", "CombinedScore", "Cusum", "DetectorScore", "Guard", "GuardMonitor", "GuardWrapper",
    "GuardedPolicy", "MemberScore", "MidEpisodeShift", "Score", "SequentialGuard", "WindowMean", "conformal_threshold",
    "make_score", "min_calibration_size", "model_fingerprint",
]
