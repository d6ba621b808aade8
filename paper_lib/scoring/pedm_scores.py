"""Every scorer on one run's PEDM-protocol collection: per-step scores and PEDM's metrics (issue 69).

Scorers: the agent's own measures (`measures.estimates.uncertainty`: none for a baseline with continuous actions)
and the peer detectors (`peer_scores.PEER_DETECTORS`). Transition t is scored once s_{t+1} exists (the first state
a perturbation injected at step t can change): the peer detectors as `peer_scores` says, the agent's measures on
s_{t+1} as its policy sees it. Higher = more likely OOD for every scorer.

Metrics per (scorer, kind, severity), as PEDM reports them (`metrics.injection_metrics`: pooled per-step AUROC,
AP = ``aupr_out``, FPR@95; episodes that ended before their injection left out), our cluster-bootstrap AUROC
interval (clusters = episodes; every scorer of one (kind, severity) draws the same resamples, so differences
between scorers are paired). `severity_means` rows (kind ``mean``) are PEDM's summary.

What notebook 14 adds from a run's stored steps (`step_metrics`, computed when it is built): the detection delay
(`metrics.detection_delays`) at a threshold calibrated on the held-out ID episodes (`metrics.episode_threshold`),
the time-matched AUROC (`metrics.time_matched_auroc`), and the ``clock``: the step index as a scorer, which PEDM's
pooled AUROC rewards because perturbed steps come later (a reference, in no claim).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import pandas as pd

from paper_lib.scoring.metrics import (detection_delays, episode_threshold, injection_metrics, severity_means,
                                       time_matched_auroc)
from paper_lib.scoring.peer_scores import PEER_DETECTORS, PeerDetectors, peer_scores

#: A function that scores raw observations with the agent's own measures ({} for a baseline with continuous actions).
MeasureFn = Callable[[np.ndarray], Mapping[str, np.ndarray]]
#: The condition index of the held-out ID episodes in a steps table (the test conditions count from 0).
THRESHOLD_CONDITION = -1
METRIC_COLUMNS = ("auroc", "aupr_out", "fpr_at_95_tpr", "auroc_ci_low", "auroc_ci_high", "n_episodes",
                  "n_episodes_dropped", "n_id", "n_ood")
#: The step index as a scorer: what PEDM's pooled AUROC gives for knowing only the time (`step_metrics`).
CLOCK = "clock"
#: `step_metrics`' columns beside (scorer, kind, severity): computed from stored steps, not written by the stage.
STEP_COLUMNS = ("auroc_time_matched", "delay_median", "delay_mean", "detected", "false_alarm", "threshold",
                "false_alarm_bound")
#: The pooled metrics the clock gets (the other scorers' are the stage's, from full-precision scores).
CLOCK_COLUMNS = ("auroc", "aupr_out", "fpr_at_95_tpr")


def score_collection(data: Mapping[str, np.ndarray], detectors: PeerDetectors, measures: MeasureFn
                     ) -> dict[str, np.ndarray]:
    """One score per transition of ``data`` for every scorer: the agent's measures first, then PEER_DETECTORS."""
    own = {name: np.asarray(values, dtype=float) for name, values in measures(np.asarray(data["next_obs"])).items()}
    clash = sorted(set(own) & set(PEER_DETECTORS))
    if clash:
        raise ValueError(f"measure name(s) {clash} clash with the peer detectors' names; rename the measure")
    return {**own, **peer_scores(detectors, data)}


def steps_table(threshold: Mapping[str, np.ndarray], tests: Mapping[tuple[str, str], Mapping[str, np.ndarray]],
                detectors: PeerDetectors, measures: MeasureFn) -> tuple[pd.DataFrame, list[tuple[str, str]]]:
    """Every scored step: the held-out ID episodes (condition -1), then each test collection (condition i, the i-th
    key of ``tests``); columns condition, episode, step, label, then one per scorer. Returns the conditions too."""
    conditions = list(tests)
    parts = []
    for index, data in [(THRESHOLD_CONDITION, threshold), *enumerate(tests.values())]:
        scores = score_collection(data, detectors, measures)
        parts.append(pd.DataFrame({"condition": index, "episode": np.asarray(data["episode"]),
                                   "step": np.asarray(data["step"]), "label": np.asarray(data["label"]), **scores}))
    names = [list(p.columns[4:]) for p in parts]
    if any(n != names[0] for n in names):
        raise ValueError(f"the collections were scored by different scorers ({names}); score them with one agent")
    return pd.concat(parts, ignore_index=True), conditions


def scorer_names(steps: pd.DataFrame) -> list[str]:
    return [c for c in steps.columns if c not in ("condition", "episode", "step", "label")]


def protocol_metrics(steps: pd.DataFrame, conditions: list[tuple[str, str]], seed: int, n_boot: int) -> pd.DataFrame:
    """One row per (scorer, kind, severity) with METRIC_COLUMNS, then PEDM's per-severity means (kind ``mean``)."""
    rows = []
    for scorer in scorer_names(steps):
        for index, (kind, severity) in enumerate(conditions):
            part = steps[steps["condition"] == index]
            s, y, ep = part[scorer].to_numpy(), part["label"].to_numpy(), part["episode"].to_numpy()
            row = injection_metrics(s, y, ep, rng=np.random.default_rng([seed, index]), n_boot=n_boot)
            rows.append({"scorer": scorer, "kind": kind, "severity": severity,
                         **{k: row[k] for k in METRIC_COLUMNS if k in row}})
    per_kind = pd.DataFrame(rows, columns=["scorer", "kind", "severity", *METRIC_COLUMNS])
    means = severity_means(per_kind, by=("scorer", "severity")).assign(kind="mean")
    out = pd.concat([per_kind, means], ignore_index=True)[list(per_kind.columns)]
    counts = ["n_episodes", "n_episodes_dropped", "n_id", "n_ood"]
    out[counts] = out[counts].astype("Int64")  # whole numbers, empty on the mean rows
    return out


def step_metrics(steps: pd.DataFrame, conditions: list[tuple[str, str]]) -> pd.DataFrame:
    """Per (scorer, kind, severity), STEP_COLUMNS from a run's steps table, and the CLOCK's rows (CLOCK_COLUMNS and
    its time-matched AUROC, no delay); kind ``mean``: the per-severity means of the AUROC columns.

    Each scorer's threshold is calibrated once on the held-out ID episodes (condition -1, `episode_threshold`);
    ``detected`` is the share of injected episodes flagged at or after the injection, ``false_alarm`` the share
    flagged before it (at most ``false_alarm_bound`` in expectation for an ID episode)."""
    held_out = steps[steps["condition"] == THRESHOLD_CONDITION]
    if held_out.empty:
        raise ValueError("the steps table has no held-out ID steps (condition -1): they set the delay threshold "
                         "and the time-matched AUROC's ID steps")
    rows = []
    for scorer in [*scorer_names(steps), CLOCK]:
        clock = scorer == CLOCK
        id_s = held_out["step" if clock else scorer].to_numpy(float)
        if not clock:
            threshold, bound = episode_threshold(id_s, held_out["episode"].to_numpy())
        for index, (kind, severity) in enumerate(conditions):
            part = steps[steps["condition"] == index]
            s = part["step" if clock else scorer].to_numpy(float)
            y, ep, t = part["label"].to_numpy(), part["episode"].to_numpy(), part["step"].to_numpy()
            row: dict = {"scorer": scorer, "kind": kind, "severity": severity,
                         "auroc_time_matched": time_matched_auroc(s, y, t, id_s, held_out["step"].to_numpy())}
            if clock:
                pooled = injection_metrics(s, y, ep)
                row |= {k: pooled[k] for k in CLOCK_COLUMNS}
            else:
                delays = detection_delays(s, y, ep, threshold)
                row |= {"delay_median": float(delays["delay"].median()), "delay_mean": float(delays["delay"].mean()),
                        "detected": float(delays["delay"].notna().mean()),
                        "false_alarm": float(delays["false_alarm"].mean()), "threshold": threshold,
                        "false_alarm_bound": bound}
            rows.append(row)
    per_kind = pd.DataFrame(rows, columns=["scorer", "kind", "severity", *CLOCK_COLUMNS, *STEP_COLUMNS])
    means = severity_means(per_kind, by=("scorer", "severity"), columns=(*CLOCK_COLUMNS, "auroc_time_matched"))
    return pd.concat([per_kind, means.assign(kind="mean")], ignore_index=True)[list(per_kind.columns)]
