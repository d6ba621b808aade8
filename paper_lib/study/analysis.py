"""The study's trials as a table, and what the paper reads from them: Pareto fronts, best configurations,
ablations along the number of members and the dropout probability, and the share of performant configurations.

Rewards have different scales per environment, so wherever environments are pooled the reward is
min-max normalized per (algorithm, environment) over all COMPLETE trials of every method there:
0 is the worst and 1 the best configuration any method found.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import optuna
import pandas as pd

from paper_lib.methods.networks import METHODS
from paper_lib.study.config import parse_study_name

KEYS = ["algo", "env", "method"]
#: AUROC of a detector that guesses: the reference point of every hypervolume.
CHANCE_AUROC = 0.5


#: The columns of `load_trials` that do not depend on the search space (an empty storage still has them).
TRIAL_COLUMNS = ["study", *KEYS, "number", "state", "reward", "auroc", "seed", "retried_from", "fail_reason",
                 "surplus", "worker", "seconds", "reward_std", "final_training_reward", "auroc_measure", "config"]
#: A study's `progress` status once it holds its target of COMPLETE trials.
DONE = "done"
#: A study's `progress` status while its stored trials were trained with an older recipe of its env.
OTHER_RECIPE = "another recipe, to train again"
#: What `reading` says for an (algorithm, env) whose studies are not all done.
NOT_READ = "not read yet"


def load_trials(storage: str | optuna.storages.BaseStorage, names: Iterable[str] | None = None,
                missing_ok: bool = False) -> pd.DataFrame:
    """One row per trial of every study in `storage` (or of `names`): state, objectives, seed, settings, scores.

    A name the storage lacks is an error, unless `missing_ok`: a sweep of hours is read while it runs, and the
    studies it has not reached yet simply contribute no rows (`progress` says which).
    """
    stored = set(optuna.get_all_study_names(storage=storage))
    names = list(names) if names is not None else sorted(stored)
    missing = [name for name in names if name not in stored]
    if missing and not missing_ok:
        raise ValueError(f"the storage has no study {missing[0]!r} (nor {len(missing) - 1} more); run its trials first: "
                         f"python -m paper_lib.study.worker --study {missing[0]}  (or --all)")
    rows = []
    for name in (name for name in names if name in stored):
        algo, env_id, method = parse_study_name(name)
        study = optuna.load_study(study_name=name, storage=storage)
        for t in study.get_trials(deepcopy=False):
            attrs = t.user_attrs
            row = {"study": name, "algo": algo, "env": env_id, "method": method, "number": t.number,
                   "state": t.state.name, "reward": t.values[0] if t.values else np.nan,
                   "auroc": t.values[1] if t.values else np.nan, "seed": attrs.get("seed"),
                   "retried_from": t.system_attrs.get("failed_trial"), "fail_reason": attrs.get("fail_reason"),
                   "surplus": bool(attrs.get("surplus", False)), "worker": attrs.get("worker"),
                   "seconds": attrs.get("seconds"), "reward_std": attrs.get("reward_std"),
                   "final_training_reward": attrs.get("final_training_reward"),
                   "auroc_measure": attrs.get("auroc_measure"), "config": attrs.get("config"),
                   **{k: v for k, v in attrs.items() if k.startswith("auroc_") and k != "auroc_measure"},
                   **t.params}
            rows.append(row)
    return pd.DataFrame(rows) if rows else pd.DataFrame(columns=TRIAL_COLUMNS)


def progress(trials: pd.DataFrame, targets: dict[str, int], other_recipe: Iterable[str] = ()) -> pd.DataFrame:
    """Per configured study (name -> target of COMPLETE trials): its trials so far and whether it is done.
    A study in `other_recipe` (paper_lib.study.recipe) shows as such, and its trials should not be in `trials`."""
    rows, other_recipe = [], set(other_recipe)
    for name, target in targets.items():
        mine = trials[trials["study"] == name]
        n_complete = int((mine["state"] == "COMPLETE").sum())
        status = DONE if n_complete >= target else ("in progress" if len(mine) else "not started")
        if name in other_recipe:
            status = OTHER_RECIPE
        rows.append({"study": name, **dict(zip(KEYS, parse_study_name(name))), "target": target,
                     "complete": n_complete, "failed": int((mine["state"] == "FAIL").sum()), "status": status})
    return pd.DataFrame(rows)


def progress_caption(progress_table: pd.DataFrame) -> str:
    """How far the sweep is, for every caption: studies at their target and COMPLETE trials of all targets."""
    done = int((progress_table["status"] == DONE).sum())
    trials = int(progress_table[["complete", "target"]].min(axis=1).sum())
    stale = int((progress_table["status"] == OTHER_RECIPE).sum())
    older = f"; {stale} studies of an older recipe left out, to train again" if stale else ""
    return (f"{done} of {len(progress_table)} studies at their trial target, {trials} of "
            f"{int(progress_table['target'].sum())} trials{older}")


def complete(df: pd.DataFrame) -> pd.DataFrame:
    """COMPLETE trials only, with `reward_norm` (min-max per algorithm and env over every method's trials)."""
    done = df[df["state"] == "COMPLETE"].copy()
    grouped = done.groupby(["algo", "env"])["reward"]
    low, high = grouped.transform("min"), grouped.transform("max")
    done["reward_norm"] = np.where(high > low, (done["reward"] - low) / (high - low).where(high > low, 1.0), 1.0)
    return done


def pareto_mask(points: np.ndarray) -> np.ndarray:
    """True for the points no other point dominates (both coordinates maximized)."""
    points = np.asarray(points, dtype=float)
    n = len(points)
    mask = np.ones(n, dtype=bool)
    for i in range(n):
        others = np.delete(points, i, axis=0)
        dominated = np.all(others >= points[i], axis=1) & np.any(others > points[i], axis=1)
        mask[i] = not dominated.any()
    return mask


def hypervolume_2d(points: np.ndarray, reference: tuple[float, float]) -> float:
    """Area dominated by `points` (both maximized) and bounded below by `reference`: the front's size in one number."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = pts[(pts[:, 0] > reference[0]) & (pts[:, 1] > reference[1])]
    area, top = 0.0, reference[1]
    for x, y in sorted(map(tuple, pts), key=lambda p: -p[0]):
        if y > top:
            area += (x - reference[0]) * (y - top)
            top = y
    return float(area)


def with_fronts(done: pd.DataFrame) -> pd.DataFrame:
    """`done` plus `is_pareto`: on its own study's (algorithm, env, method) front of reward vs AUROC."""
    out = done.copy()
    out["is_pareto"] = False
    for idx in out.groupby(KEYS).groups.values():
        out.loc[idx, "is_pareto"] = pareto_mask(out.loc[idx, ["reward", "auroc"]].to_numpy())
    return out


def study_summary(df: pd.DataFrame, reward_threshold: float, auroc_threshold: float) -> pd.DataFrame:
    """Per study: trials by state, best objectives, front size, hypervolume and the performant configurations.

    A configuration is *performant* when its normalized reward is at least `reward_threshold` and its AUROC
    at least `auroc_threshold`. The hypervolume is measured in (normalized reward, AUROC) above (0, 0.5).
    The median normalized reward shows how much the reward objective separates: near 1, most configurations
    reach the env's best reward (short training that only learns to survive), and AUROC decides.
    """
    done = with_fronts(complete(df))
    finished = dict(iter(done.groupby(KEYS)))
    rows = []
    for keys, group in df.groupby(KEYS):
        ok = finished.get(keys, done.iloc[0:0])
        performant = (ok["reward_norm"] >= reward_threshold) & (ok["auroc"] >= auroc_threshold)
        rows.append({**dict(zip(KEYS, keys)), "complete": len(ok), "failed": int((group["state"] == "FAIL").sum()),
                     "retried": int(group["retried_from"].notna().sum()),
                     "best_reward": ok["reward"].max(), "median_reward": ok["reward"].median(),
                     "median_reward_norm": ok["reward_norm"].median(), "best_auroc": ok["auroc"].max(),
                     "front_size": int(ok["is_pareto"].sum()),
                     "hypervolume": hypervolume_2d(ok[["reward_norm", "auroc"]].to_numpy(), (0.0, CHANCE_AUROC)),
                     "performant": int(performant.sum()),
                     "performant_share": float(performant.mean()) if len(ok) else np.nan})
    out = pd.DataFrame(rows)
    return _method_order(out)


def _method_order(df: pd.DataFrame) -> pd.DataFrame:
    order = {m: i for i, m in enumerate(METHODS)}
    return df.sort_values(["algo", "env", "method"], key=lambda s: s.map(order) if s.name == "method" else s,
                          ignore_index=True)


def best_configs(df: pd.DataFrame) -> pd.DataFrame:
    """Every study's Pareto-optimal trials, best reward first, with their seed and searched settings."""
    fronts = with_fronts(complete(df))
    front = fronts[fronts["is_pareto"]]
    settings = [c for c in df.columns if c not in _NOT_SETTINGS and not c.startswith("auroc_")]
    columns = [*KEYS, "number", "seed", "reward", "auroc", *[c for c in settings if front[c].notna().any()]]
    return _method_order(front.sort_values(["algo", "env", "method", "reward"], ascending=[True, True, True, False])
                         [columns]).reset_index(drop=True)


_NOT_SETTINGS = {"study", "algo", "env", "method", "number", "state", "reward", "auroc", "seed", "retried_from",
                 "fail_reason", "surplus", "worker", "seconds", "reward_std", "final_training_reward",
                 "auroc_measure", "config", "reward_norm", "is_pareto"}


def ablation_frame(df: pd.DataFrame, axis: str, methods: list[str]) -> pd.DataFrame:
    """COMPLETE trials of `methods` with their value of `axis` (k or p): the rows the ablation plots average."""
    done = complete(df)
    if axis not in done.columns:
        return done.iloc[0:0].assign(**{axis: []})
    rows = done[done["method"].isin(methods) & done[axis].notna()].copy()
    rows[axis] = rows[axis].astype(float).round(6)
    return rows


def ablation_table(rows: pd.DataFrame, axis: str) -> pd.DataFrame:
    """Mean, std and count of the normalized reward and the AUROC per method and `axis` value, over all envs."""
    stats = rows.groupby(["method", axis]).agg(reward_norm_mean=("reward_norm", "mean"),
                                               reward_norm_std=("reward_norm", "std"),
                                               auroc_mean=("auroc", "mean"), auroc_std=("auroc", "std"),
                                               trials=("auroc", "size"))
    return stats.reset_index()


def _leaders(group: pd.DataFrame) -> dict[str, object]:
    """The method(s) with the most performant configurations (ties joined) and the one with the largest hypervolume."""
    most = group["performant"].max()
    largest = group.loc[group["hypervolume"].idxmax()]
    return {"most_performant": ", ".join(group[group["performant"] == most]["method"]), "performant": int(most),
            "largest_hypervolume": largest["method"], "hypervolume": float(largest["hypervolume"])}


#: `reading`'s columns: the leaders over every method, then over the member methods only (`_members`).
READING_COLUMNS = ["most_performant", "performant", "largest_hypervolume", "hypervolume"]


def studies_done(progress_table: pd.DataFrame, algo: str, env: str) -> tuple[int, int]:
    """(studies at their trial target, studies) of one (algorithm, env) in a `progress` table."""
    mine = progress_table[(progress_table["algo"] == algo) & (progress_table["env"] == env)]
    return int((mine["status"] == DONE).sum()), len(mine)


def reading(summary: pd.DataFrame, progress_table: pd.DataFrame | None = None) -> pd.DataFrame:
    """Per (algorithm, env): which method has the most performant configurations and the largest hypervolume.

    Read twice: over every method, and over the member methods only (`..._members` columns). The paper's
    claim compares the uncertainty methods among themselves; the baseline scores OOD with a member-free
    detector on its features, which can separate an easy OOD set (the noise) perfectly, so it is the
    reference point rather than a contender.

    With `progress_table`, an (algorithm, env) whose studies are not all done is listed but not read: a method
    whose study has not run would lose by default, and a half-run study by having fewer trials.
    """
    pairs = summary[["algo", "env"]] if progress_table is None else progress_table[["algo", "env"]]
    members_only = [f"{c}_members" for c in READING_COLUMNS]
    rows = []
    for algo, env in sorted(set(map(tuple, pairs.to_numpy()))):
        group = summary[(summary["algo"] == algo) & (summary["env"] == env)]
        done, total = (len(group),) * 2 if progress_table is None else studies_done(progress_table, algo, env)
        row = {"algo": algo, "env": env, "studies_done": f"{done} of {total}"}
        members = group[group["method"] != "baseline"]
        if done < total:
            row.update({c: NOT_READ if c.startswith(("most", "largest")) else ""
                        for c in READING_COLUMNS + members_only})
        else:
            row.update(_leaders(group))
            row.update({f"{c}_members": v for c, v in _leaders(members).items()} if len(members) else
                       dict.fromkeys(members_only, ""))
        rows.append(row)
    return pd.DataFrame(rows)


#: Appendix C's readings of fig:scatter_other_algs (A2C and TRPO on HalfCheetah), in its words.
PAPER_OTHER_ALGORITHMS = {
    "members_behind_baseline": "all sample-based methods seem to lack behind the baseline",
    "masksembles_leads_members": "Masksembles still outperforms the other approaches [...] it also achieves the "
                                 "overall best training results",
}
#: `other_algorithms_vs_paper`'s columns (an empty table has them too).
OTHER_ALGORITHMS_COLUMNS = ["algo", "env", "baseline_best_reward", "best_member", "best_member_reward",
                            "largest_hypervolume_member", "agrees_behind_baseline",
                            "agrees_masksembles_leads"]


def other_algorithms_vs_paper(summary: pd.DataFrame, progress_table: pd.DataFrame | None = None) -> pd.DataFrame:
    """Appendix C's two readings checked per (algorithm, env) other than PPO, once all its studies are done.

    "Behind the baseline": every member method's best reward is below the baseline's. "Masksembles
    outperforms the other approaches": Masksembles has the best reward among the member methods (the
    appendix speaks of its best training results); the member with the largest hypervolume is shown beside it.
    """
    rows = []
    others = summary[summary["algo"] != "ppo"]
    for (algo, env), group in others.groupby(["algo", "env"], sort=True):
        if progress_table is not None:
            done, total = studies_done(progress_table, algo, env)
            if done < total:
                continue
        baseline, members = group[group["method"] == "baseline"], group[group["method"] != "baseline"]
        if baseline.empty or members.empty:
            continue
        best = members.loc[members["best_reward"].idxmax()]
        behind = bool((members["best_reward"] < baseline["best_reward"].iloc[0]).all())
        rows.append({"algo": algo, "env": env, "baseline_best_reward": float(baseline["best_reward"].iloc[0]),
                     "best_member": best["method"], "best_member_reward": float(best["best_reward"]),
                     "largest_hypervolume_member": members.loc[members["hypervolume"].idxmax(), "method"],
                     "agrees_behind_baseline": behind,
                     "agrees_masksembles_leads": best["method"] == "masksembles"})
    return pd.DataFrame(rows, columns=OTHER_ALGORITHMS_COLUMNS)
