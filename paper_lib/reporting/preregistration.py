"""The claims' design, fixed before the new seeds: params.yaml's `preregistration` and the power behind its counts.

Issue 66 asks that every rule, margin, family and seed count be settled and written down before any run of the
new seeds (Atari 1-2, MuJoCo 3-4) lands its scores. `Preregistration` reads that entry; `power_table` computes,
from the per-seed numbers of the seeds the entry names (0-2, committed before it), the seeds each (claim, env)
needs for an 80% chance that its rule decides (`reporting.power`). scripts/power_analysis.py writes that table once
into data/preregistration/ and the claims read it from there: a cell whose count exceeds its planned seeds reads
"undecidable at N seeds (needs about M)" when its interval does not decide at N, as decided here in advance.
docs/preregistration.md states every rule in words.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from paper_lib.common.checks import check_keys
from paper_lib.reporting.power import MAX_SEEDS, all_of, any_of, at_least, clear_probabilities, seeds_needed

KEYS = ("registered", "level", "power", "reward_margin", "js_threshold", "min_ood_conditions", "planned_seeds",
        "power_seeds", "power_file", "auroc_order_states", "speed", "pedm")
SPEED_KEYS = ("registered", "timings", "inference", "training", "margin", "min_repetitions")
PEDM_KEYS = ("registered", "metric", "versus", "seeds")
POWER_COLUMNS = ["claim", "env", "cells", "estimate", "seeds_at_hand", "planned_seeds", "decide_at_planned",
                 "seeds_needed", "note"]
MEMBER_METHODS = ("masksembles", "mc_dropout", "mc_dropconnect", "ensemble")


@dataclass(frozen=True)
class Preregistration:
    """What params.yaml's `preregistration` fixes (docs/preregistration.md says why each)."""
    registered: str                      # the date the entry was fixed, before any new seed's scores
    level: float                         # every interval's two-sided level
    power: float                         # the chance of a decision a seed count is sized for
    reward_margin: float                 # "keeps the reward": a loss within this share of the baseline's reward
    js_threshold: float                  # "ranks like policy std": Spearman rho at least this
    min_ood_conditions: int              # fewer distinct OOD conditions in a run: the cell is not testable
    planned_seeds: dict[str, list[int]]  # per env family (MuJoCo, Atari): the seeds every verdict waits for
    power_seeds: dict[str, list[int]]    # per env family: the seeds the power analysis read (those committed
                                         # before registration)
    power_file: str                      # the power table, relative to the repository root
    auroc_order_states: str              # which states the AUROC-order claim compares the methods on
    speed: dict[str, Any]                # the speed claim (issue 70): its benchmark file, timings, margin, repetitions
    pedm: dict[str, Any]                 # the PEDM claim (issue 69): its metric, the detector compared, its seeds

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> Preregistration:
        entry = params.get("preregistration")
        if not isinstance(entry, dict):
            raise ValueError("params.yaml has no `preregistration` entry: the claims' rules and seed counts are "
                             "fixed there (docs/preregistration.md); restore it from git.")
        check_keys(entry, "params.yaml preregistration", KEYS, KEYS, fix="restore the entry from git")
        for name, keys in (("speed", SPEED_KEYS), ("pedm", PEDM_KEYS)):
            check_keys(entry[name], f"params.yaml preregistration.{name}", keys, keys, fix="restore the entry from git")
        for name in ("planned_seeds", "power_seeds"):
            if not isinstance(entry[name], dict) or set(entry[name]) != {"MuJoCo", "Atari"}:
                raise ValueError(f"params.yaml preregistration.{name} must name MuJoCo and Atari, got "
                                 f"{entry[name]!r}; restore the entry from git.")
        return cls(**{key: entry[key] for key in KEYS})

    def planned(self, env_id: str) -> list[int]:
        return list(self.planned_seeds[family_of(env_id)])

    def power_rows(self, frame: pd.DataFrame) -> pd.DataFrame:
        """The rows of `frame` (env and seed columns) of seeds the power analysis read: each env family's own
        (Atari had only seed 0 at registration, MuJoCo seeds 0-2), so no later seed can change the registered file."""
        if frame.empty:
            return frame
        keep = [seed in self.power_seeds[family_of(env)] for env, seed in zip(frame["env"], frame["seed"])]
        return frame[np.asarray(keep, dtype=bool)]


def family_of(env_id: str) -> str:
    from paper_lib.agents.envs import is_atari

    return "Atari" if is_atari(env_id) else "MuJoCo"


def _needed(decide: Any, power: float) -> float:
    n = seeds_needed(decide, power)
    return float(n) if n is not None else np.nan


def _row(claim: str, env: str, cells: int, estimate: str, at_hand: int, planned: int, decide: Any, power: float,
         note: str = "") -> dict[str, Any]:
    needed = _needed(decide, power) if at_hand >= 2 else np.nan
    if at_hand < 2:
        note = note or f"{at_hand} seed at hand: no spread to size a count from; planned {planned} (the paper's)"
    elif np.isnan(needed):
        note = note or f"over {MAX_SEEDS} seeds"
    return {"claim": claim, "env": env, "cells": cells, "estimate": estimate, "seeds_at_hand": at_hand,
            "planned_seeds": planned, "decide_at_planned": decide(planned) if at_hand >= 2 else np.nan,
            "seeds_needed": needed, "note": note}


def _seed_values(frame: pd.DataFrame, value: str) -> pd.Series:
    return frame.set_index("seed")[value].sort_index()


def reward_power(episodes: pd.DataFrame, prereg: Preregistration) -> list[dict[str, Any]]:
    """Masksembles keeps the baseline's reward: the paired per-seed difference against -margin x baseline."""
    sampled = episodes[~episodes["deterministic"].astype(bool)]
    sampled = sampled[(sampled["method"] == "baseline") | (sampled["inference"] == "combined")]
    runs = sampled.groupby(["env", "method", "seed"], as_index=False)["reward"].mean()
    rows = []
    for env in pd.unique(runs["env"]):
        cell = runs[runs["env"] == env]
        a = _seed_values(cell[cell["method"] == "masksembles"], "reward")
        b = _seed_values(cell[cell["method"] == "baseline"], "reward")
        seeds = a.index.intersection(b.index)
        if seeds.empty:
            continue
        diff = (a[seeds] - b[seeds]).to_numpy()
        bound = -prereg.reward_margin * abs(float(b[seeds].mean()))
        effect, sd = float(diff.mean()), float(diff.std(ddof=1)) if diff.size > 1 else np.nan

        def decide(n: int, effect=effect, sd=sd, bound=bound) -> float:
            return sum(clear_probabilities(effect, sd, n, bound, prereg.level, prereg.level))

        rows.append(_row("masksembles_reward", env, 1, f"difference {effect:+.0f}, seed sd {sd:.0f}, bound {bound:+.0f}",
                         len(seeds), len(prereg.planned(env)), decide, prereg.power))
    return rows


def _pair_differences(metrics: pd.DataFrame, env: str, measure: str, a: str, b: str) -> np.ndarray:
    cell = metrics[(metrics["env"] == env) & (metrics["ood_set"] == "perturbed") & (metrics["measure"] == measure)]
    x, y = _seed_values(cell[cell["method"] == a], "auroc"), _seed_values(cell[cell["method"] == b], "auroc")
    seeds = x.index.intersection(y.index)
    return (x[seeds] - y[seeds]).to_numpy()


def _moments(diff: np.ndarray) -> tuple[float, float]:
    return float(diff.mean()), float(diff.std(ddof=1)) if diff.size > 1 else np.nan


def auroc_order_power(metrics: pd.DataFrame, prereg: Preregistration, pairs: list[tuple[str, str]],
                      measures: tuple[str, ...], states: str = "each method's own states") -> list[dict[str, Any]]:
    """Per env: both measures hold (all 4 pairs' 95% intervals above 0) or both fail (some pair's simultaneous
    interval over the 4 below 0); `metrics` are the per-seed AUROCs the claim reads (`states` names them)."""
    rows = []
    family = 1.0 - (1.0 - prereg.level) / len(pairs)
    for env in pd.unique(metrics["env"]):
        cells = {(m, p): _moments(_pair_differences(metrics, env, m, *p)) for m in measures for p in pairs}
        at_hand = min(len(_pair_differences(metrics, env, m, *p)) for m in measures for p in pairs)
        if at_hand == 0:
            continue

        def decide(n: int, cells=cells) -> float:
            holds = fails = 1.0
            for measure in measures:
                above = [clear_probabilities(*cells[(measure, p)], n, 0.0, prereg.level, family)[0] for p in pairs]
                below = [clear_probabilities(*cells[(measure, p)], n, 0.0, family, prereg.level)[1] for p in pairs]
                holds *= all_of(above)
                fails *= any_of(below)
            return holds + fails

        estimate = "; ".join(f"{m}: " + ", ".join(f"{a}-{b} {cells[(m, (a, b))][0]:+.2f} (sd {cells[(m, (a, b))][1]:.2f})"
                                                  for a, b in pairs) for m in measures)
        rows.append(_row("auroc_order", env, len(pairs) * len(measures), estimate, at_hand, len(prereg.planned(env)),
                         decide if at_hand >= 2 else (lambda n: np.nan), prereg.power,
                         f"computed from {states}" if at_hand >= 2 else ""))
    return rows


def detector_power(metrics: pd.DataFrame, prereg: Preregistration, is_detector: Any,
                   best: pd.Series) -> list[dict[str, Any]]:
    """Per env: some (method, measure) cell's simultaneous interval above its runs' best detector, or every cell's
    own 95% interval below it."""
    rows = []
    perturbed = metrics[metrics["ood_set"] == "perturbed"]
    for env in pd.unique(perturbed["env"]):
        detector = best.get((env, "perturbed"))
        if detector is None:
            continue
        members = perturbed[(perturbed["env"] == env) & ~is_detector(perturbed["measure"])]
        cells = {}
        for (method, measure), _ in members.groupby(["method", "measure"], sort=False):
            cells[(method, measure)] = _moments(_member_minus_detector(perturbed, env, method, measure, detector))
        at_hand = int(members.groupby(["method", "measure"]).size().min())
        m = len(cells)
        family = 1.0 - (1.0 - prereg.level) / m

        def decide(n: int, cells=cells, family=family) -> float:
            above = [clear_probabilities(*c, n, 0.0, family, prereg.level)[0] for c in cells.values()]
            below = [clear_probabilities(*c, n, 0.0, prereg.level, prereg.level)[1] for c in cells.values()]
            return any_of(above) + all_of(below)

        best_cell = max(cells, key=lambda k: cells[k][0])
        rows.append(_row("members_vs_detectors", env, m, f"best {best_cell[0]} {best_cell[1]} "
                         f"{cells[best_cell][0]:+.3f} (sd {cells[best_cell][1]:.3f}) vs {detector}", at_hand,
                         len(prereg.planned(env)), decide if at_hand >= 2 else (lambda n: np.nan), prereg.power))
    return rows


def _member_minus_detector(perturbed: pd.DataFrame, env: str, method: str, measure: str, detector: str) -> np.ndarray:
    cell = perturbed[(perturbed["env"] == env) & (perturbed["method"] == method)]
    x = _seed_values(cell[cell["measure"] == measure], "auroc")
    y = _seed_values(cell[cell["measure"] == detector], "auroc")
    seeds = x.index.intersection(y.index)
    return (x[seeds] - y[seeds]).to_numpy()


def levitation_power(spawn: pd.DataFrame, prereg: Preregistration) -> list[dict[str, Any]]:
    """Ant: a method flags the spawn when both log(value-std spawn ratio) > 0 and airborne AUROC - 0.5 > 0 hold; the
    claim holds when at least 3 of the 4 member methods do, and does not when 2 or more surely do not; every
    interval simultaneous over the claim's 8 (as `claims.levitation_claim`)."""
    ant = spawn[spawn["env"] == "Ant-v5"]
    if ant.empty:
        return []
    cells = {}
    for method in MEMBER_METHODS:
        rows = ant[ant["method"] == method]
        if rows.empty:
            continue
        cells[method] = (_moments(np.log(rows["value_std_spawn_ratio"].to_numpy(float))),
                         _moments(rows["value_std_airborne_auroc"].to_numpy(float) - 0.5))
    at_hand = int(ant.groupby("method").size().min())
    need = len(cells) // 2 + 1
    level = 1.0 - (1.0 - prereg.level) / (2 * len(cells))

    def decide(n: int) -> float:
        holds, fails = [], []
        for ratio, auroc in cells.values():
            r, a = clear_probabilities(*ratio, n, 0.0, level, level), clear_probabilities(*auroc, n, 0.0, level, level)
            holds.append(r[0] * a[0])
            fails.append(any_of([r[1], a[1]]))
        return at_least(holds, need) + at_least(fails, len(cells) - need + 1)

    estimate = "; ".join(f"{m}: log ratio {c[0][0]:+.2f} (sd {c[0][1]:.2f}), AUROC-0.5 {c[1][0]:+.2f} (sd {c[1][1]:.2f})"
                         for m, c in cells.items())
    return [_row("levitation", "Ant-v5", len(cells), estimate, at_hand, len(prereg.planned("Ant-v5")), decide,
                 prereg.power)]


def js_power(metrics: pd.DataFrame, prereg: Preregistration) -> list[dict[str, Any]]:
    """The JS claim's interval is over (env, method) cells, 16 per family whatever the seeds: no seed count to size."""
    rows = []
    for family in ("MuJoCo", "Atari"):
        envs = [e for e in pd.unique(metrics["env"]) if family_of(e) == family]
        if not envs:
            continue
        cells = metrics[metrics["env"].isin(envs) & (metrics["ood_set"] == "perturbed")
                        & metrics["measure"].isin(["policy_js", "policy_std"])]
        n_cells = cells.groupby(["env", "method"]).ngroups
        rows.append({"claim": "js_like_std", "env": family, "cells": n_cells, "estimate": "", "seeds_at_hand":
                     int(cells.groupby(["env", "method", "measure"])["seed"].nunique().min()),
                     "planned_seeds": len(prereg.planned_seeds[family]), "decide_at_planned": np.nan,
                     "seeds_needed": np.nan, "note": "the interval is over (env, method) cells; more seeds do not add "
                                                     "cells, only steady each cell's AUROC: no count to size"})
    return rows


def power_table(episodes: pd.DataFrame, metrics: pd.DataFrame, spawn: pd.DataFrame | None, prereg: Preregistration,
                pairs: list[tuple[str, str]], measures: tuple[str, ...], is_detector: Any,
                best: pd.Series, common: pd.DataFrame | None = None) -> pd.DataFrame:
    """Every (claim, env)'s seeds needed, from the `prereg.power_seeds` rows of the given per-seed frames; the AUROC
    order from `common` (the member methods on the baseline's states) where given, as the claim reads it."""
    episodes, metrics = prereg.power_rows(episodes), prereg.power_rows(metrics)
    spawn = prereg.power_rows(spawn) if spawn is not None else pd.DataFrame(columns=["env"])
    order = (auroc_order_power(prereg.power_rows(common), prereg, pairs, measures,
                               "the common states (the baseline's, scored by every method)")
             if common is not None else auroc_order_power(metrics, prereg, pairs, measures))
    rows = (reward_power(episodes, prereg) + order
            + levitation_power(spawn, prereg) + js_power(metrics, prereg)
            + detector_power(metrics, prereg, is_detector, best))
    return pd.DataFrame(rows, columns=POWER_COLUMNS)


def registered_counts(power: pd.DataFrame) -> dict[tuple[str, str], float]:
    """{(claim, env): seeds needed} of the power table's sized rows; inf where the count lies beyond MAX_SEEDS.
    Rows without a count (one seed at hand, or a claim no seed count sizes) are left out."""
    counts = {}
    for r in power.itertuples():
        if not np.isnan(r.seeds_needed):
            counts[(r.claim, r.env)] = float(r.seeds_needed)
        elif r.note == f"over {MAX_SEEDS} seeds":
            counts[(r.claim, r.env)] = np.inf
    return counts


def read_power(path: str | Path) -> pd.DataFrame:
    """The committed power table; one clear error when it is missing (it is written once, never rebuilt)."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"the pre-registered power table {path} is missing: it was written once by "
                         "scripts/power_analysis.py at registration; restore it from git (`git checkout -- "
                         f"{path}`), do not recompute it from later seeds.")
    table = pd.read_csv(path)
    missing = sorted(set(POWER_COLUMNS) - set(table.columns))
    if missing:
        raise ValueError(f"{path} lacks columns {missing}: restore it from git.")
    return table
