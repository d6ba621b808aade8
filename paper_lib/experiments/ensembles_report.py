"""Tables, figure and reading of 'Ensembles examined' (notebooks/11_ensembles.ipynb), from per-run files.

The expensive work (playing evaluation episodes, scoring states) is done once per combination
and per run by `python -m paper_lib.experiments.ensembles evaluate` (and, for the shared twins, by the main
pipeline); this module only reads those small files, so the notebook runs in seconds. Runs
that are not complete yet are left out here; `ensembles.missing_runs` lists them. Scores are read only with their
`provenance.json` naming what is there now (`ensembles.check_combination_provenance`, `check_own_provenance`; the
shared twins are the main matrix's scores, checked as its readers check them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import seaborn as sns
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from paper_lib.experiments.ensembles import (ASSIGNMENTS, EnsemblesConfig, check_combination_provenance,
                                             check_own_provenance, complete_combinations, complete_pairs)
from paper_lib.methods.networks import METHODS
from paper_lib.pipeline.run_results import read_evaluations, read_scores, scores_dir
from paper_lib.reporting.paper_tables import reward_table
from paper_lib.reporting.plots import seeded_jitter
from paper_lib.reporting.tables import PLUS_MINUS
from paper_lib.scoring.rewards import summarize_rewards

#: The measures of the paper's independent-ensemble AUROC table (appendix B.2).
PAPER_MEASURES = ("value_std", "policy_std", "max_prob")
METHOD = "independent_ensemble"


@dataclass
class Results:
    rewards: pd.DataFrame  # one row per evaluation episode
    metrics: pd.DataFrame  # one row per (agent, OOD set, measure)


def _frame(parts: list[pd.DataFrame]) -> pd.DataFrame:
    parts = [p for p in parts if not p.empty]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def read_independent(cfg: EnsemblesConfig) -> Results:
    """Episodes and OOD metrics of every complete combination (columns env, combination, members, ...); scores whose
    record is missing or names other inputs than the combination's current files are refused."""
    done = complete_combinations(cfg)
    for env_id, _, members in done:
        check_combination_provenance(cfg, env_id, members)
    return Results(_frame([pd.read_csv(cfg.combination_evaluation(e, m)) for e, _, m in done]),
                   _frame([pd.read_csv(cfg.combination_metrics(e, m)) for e, _, m in done]))


def read_own_vs_shared(cfg: EnsemblesConfig) -> Results:
    """Episodes and OOD metrics of both twins of every complete, comparable pair (column `assignment`); an own run's
    scores whose record is missing or names other inputs are refused (the shared twins': as the main matrix's)."""
    runs = complete_pairs(cfg)
    if not runs:
        return Results(pd.DataFrame(), pd.DataFrame())
    for run in runs:
        check_own_provenance(cfg, *run)
    rewards = [read_evaluations(cfg.tree(a), runs).assign(assignment=a) for a in ASSIGNMENTS]
    metrics = [read_scores(cfg.tree(a), runs, "metrics").assign(assignment=a) for a in ASSIGNMENTS]
    return Results(_frame(rewards), _frame(metrics))


def all_metrics(*results: Results) -> pd.DataFrame:
    """Every OOD metric row of the given results in one frame (what ensembles_ood_metrics.csv holds)."""
    return _frame([r.metrics for r in results])


# ----------------------------------------------------------------------- independent ensembles


def _cell(mean: float, std: float, n: int) -> str:
    if np.isnan(mean):
        return "n/a"
    return f"{mean:.2f}" if n < 2 or np.isnan(std) else f"{mean:.2f} {PLUS_MINUS} {std:.2f}"


def independent_reward_summary(rewards: pd.DataFrame) -> pd.DataFrame:
    """Per env, inference and action mode: mean over the combinations of each one's episode mean, std across them."""
    columns = ["env", "method", "inference", "deterministic", "mean", "std", "n_combinations", "n_episodes", "std_over"]
    if rewards.empty:
        return pd.DataFrame(columns=columns)
    out = summarize_rewards(rewards.assign(seed=rewards["combination"]))
    out = out.rename(columns={"n_seeds": "n_combinations"})
    return out.assign(std_over=out["std_over"].replace({"seeds": "combinations"}))[columns]


def independent_reward_table(summary: pd.DataFrame, envs: list[str]) -> pd.DataFrame:
    """The appendix's reward table: rows inference x actions, columns env in `envs` order (the AUROC table's),
    cells 'mean ± std over combinations', '(n=...)' after each where envs have different counts (an env with one
    combination so far has the std over its episodes, as `summarize_rewards` gives for one seed)."""
    if summary.empty:
        return pd.DataFrame(columns=["method", "inference", "actions"])
    wide = reward_table(summary.rename(columns={"n_combinations": "n_seeds"}), [METHOD])
    return wide[["method", "inference", "actions", *[e for e in envs if e in wide.columns]]]


def auroc_summary(metrics: pd.DataFrame, keys: list[str], over: str) -> pd.DataFrame:
    """AUROC mean, std (ddof=1) and count over `over` (combinations or seeds) per `keys`."""
    columns = [*keys, "auroc", "auroc_std", f"n_{over}"]
    if metrics.empty:
        return pd.DataFrame(columns=columns)
    out = metrics.groupby(keys, sort=False)["auroc"].agg(auroc="mean", auroc_std="std", n="count").reset_index()
    return out.rename(columns={"n": f"n_{over}"})[columns]


def independent_auroc_table(summary: pd.DataFrame, envs: list[str], ood_set: str = "perturbed",
                            measures: tuple[str, ...] = PAPER_MEASURES) -> pd.DataFrame:
    """The appendix's AUROC table: rows measure, columns env, cells 'mean ± std over combinations' ('n/a': none)."""
    sub = summary[summary["ood_set"] == ood_set] if not summary.empty else summary
    rows = []
    for measure in measures:
        row = {"measure": measure}
        for env_id in envs:
            hit = sub[(sub["env"] == env_id) & (sub["measure"] == measure)] if not sub.empty else sub
            row[env_id] = (_cell(hit["auroc"].iloc[0], hit["auroc_std"].iloc[0], hit["n_combinations"].iloc[0])
                           if len(hit) else "n/a")
        rows.append(row)
    return pd.DataFrame(rows, columns=["measure", *envs])


def independent_vs_paper(reward_summary: pd.DataFrame, auroc: pd.DataFrame, reported: pd.DataFrame,
                         envs: list[str]) -> pd.DataFrame:
    """Our numbers (deterministic rewards, perturbed-set AUROC, mean over combinations) beside the paper's.

    Every reported number of our envs gets a row; `note` says why ours is missing where it is.
    """
    ours = []
    if not reward_summary.empty:
        det = reward_summary[reward_summary["deterministic"].astype(bool)]
        for row in det.itertuples():
            quantity = "reward_combined" if row.inference == "combined" else "reward_single"
            ours.append(dict(quantity=quantity, env=row.env, ours=row.mean, ours_std=row.std,
                             n_combinations=row.n_combinations))
    if not auroc.empty:
        for row in auroc[auroc["ood_set"] == "perturbed"].itertuples():
            ours.append(dict(quantity=f"rocauc_{row.measure}", env=row.env, ours=row.auroc, ours_std=row.auroc_std,
                             n_combinations=row.n_combinations))
    ours_df = pd.DataFrame(ours, columns=["quantity", "env", "ours", "ours_std", "n_combinations"])
    paper = reported[reported["env"].isin(envs)]
    merged = paper.merge(ours_df, on=["quantity", "env"], how="left")
    merged = merged.assign(difference=merged["ours"] - merged["paper"])
    evaluated_envs = set(ours_df["env"])
    merged["n_combinations"] = merged["n_combinations"].astype("Int64")
    merged["note"] = [
        (_one_combination_note(q) if not pd.isna(n) and n == 1 else "") if not np.isnan(o) else
        ("not trained or collected yet" if env not in evaluated_envs else
         "max_prob is defined for discrete actions only" if q == "rocauc_max_prob" else "not evaluated")
        for o, env, q, n in zip(merged["ours"], merged["env"], merged["quantity"], merged["n_combinations"])]
    return merged[["quantity", "env", "ours", "ours_std", "n_combinations", "paper", "difference", "note"]]


def shared_ensemble_metrics(cfg: EnsemblesConfig) -> pd.DataFrame:
    """OOD metrics of the main matrix's scored Ensemble runs (shared buffer) in the independent ensembles' envs."""
    runs = [r for r in cfg.run.runs() if r[1] == "ensemble" and r[0] in cfg.envs
            and (scores_dir(cfg.run, *r) / "metrics.csv").is_file()]
    return read_scores(cfg.run, runs, "metrics") if runs else pd.DataFrame()


def _one_combination_note(quantity: str) -> str:
    """While an env has one combination, a reward's std is over that combination's episodes (as
    `summarize_rewards` does for one seed) and an AUROC has none: say so, not 'std over combinations'."""
    return ("one combination so far: ours_std is over its episodes" if quantity.startswith("reward")
            else "one combination so far: no std")


def _spread_over(n_combinations: int) -> str:
    return "std over combinations" if n_combinations >= 2 else "std over episodes (one combination so far)"


def independent_reading(vs_paper: pd.DataFrame, shared_metrics: pd.DataFrame,
                        measures: tuple[str, ...] = ("value_std", "policy_std")) -> list[str]:
    """Sentences made only of the numbers, one per env for each of appendix B.2's two claims: combining the
    members costs reward against a single member, and independent members detect OOD worse than the
    shared-buffer Ensemble (the main matrix's, perturbed states)."""
    ours = vs_paper.dropna(subset=["ours"]).set_index(["env", "quantity"])
    if ours.empty:
        return ["No independent ensemble is complete yet: the members listed as missing above come first."]
    perturbed = shared_metrics[shared_metrics["ood_set"] == "perturbed"] if not shared_metrics.empty else shared_metrics
    lines = []
    for env_id in dict.fromkeys(ours.index.get_level_values("env")):
        cells = ours.loc[env_id]
        if {"reward_combined", "reward_single"} <= set(cells.index):
            combined, single = cells.loc["reward_combined"], cells.loc["reward_single"]
            gap, spread = combined["ours"] - single["ours"], max(combined["ours_std"], single["ours_std"])
            side = "larger than" if abs(gap) > spread else "within"
            n = int(min(combined["n_combinations"], single["n_combinations"]))
            lines.append(f"{env_id}, reward (deterministic, mean over {n} combination{'s' if n != 1 else ''}): "
                         f"combined inference {combined['ours']:.1f}, a single member {single['ours']:.1f} "
                         f"(combined - single {gap:+.1f}, {side} the larger {_spread_over(n)}, {spread:.1f}); "
                         f"the paper {combined['paper']:.1f} and {single['paper']:.1f}.")
        parts = []
        for measure in measures:
            quantity = f"rocauc_{measure}"
            shared = perturbed[(perturbed["env"] == env_id) & (perturbed["measure"] == measure)] \
                if not perturbed.empty else perturbed
            if quantity in cells.index and len(shared):
                parts.append(f"{measure} {cells.loc[quantity, 'ours']:.2f} independent vs "
                             f"{shared['auroc'].mean():.2f} shared-buffer Ensemble ({len(shared)} seed(s))")
        if parts:
            lines.append(f"{env_id}, AUROC on perturbed states: " + "; ".join(parts) + ".")
    return lines


# ------------------------------------------------------------------------------- own vs shared

#: The compared quantities: combined-inference reward per action mode, a single member's deterministic reward
#: (members that learn well alone can still cancel out when combined), AUROC on the perturbed set.
QUANTITIES = ("reward (deterministic)", "reward (sampled)", "reward (single member, deterministic)",
              "AUROC value_std", "AUROC policy_std")


def own_vs_shared_per_seed(evaluated: Results) -> pd.DataFrame:
    """One value per (env, method, seed, assignment, quantity): the tidy input of the table and the figure."""
    columns = ["env", "method", "seed", "assignment", "quantity", "value"]
    parts = []
    if not evaluated.rewards.empty:
        combined = evaluated.rewards[evaluated.rewards["inference"] == "combined"]
        per = combined.groupby(["env", "method", "seed", "assignment", "deterministic"])["reward"].mean().reset_index()
        per["quantity"] = np.where(per["deterministic"], QUANTITIES[0], QUANTITIES[1])
        parts.append(per.rename(columns={"reward": "value"})[columns])
        rewards = evaluated.rewards
        single = rewards[(rewards["inference"] == "single") & rewards["deterministic"].astype(bool)]
        single = single.groupby(["env", "method", "seed", "assignment"])["reward"].mean().reset_index()
        parts.append(single.rename(columns={"reward": "value"}).assign(quantity=QUANTITIES[2])[columns])
    if not evaluated.metrics.empty:
        m = evaluated.metrics
        m = m[(m["ood_set"] == "perturbed") & m["measure"].isin(["value_std", "policy_std"])]
        parts.append(m.assign(quantity="AUROC " + m["measure"], value=m["auroc"])[columns])
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=columns)
    return out.reset_index(drop=True)


def own_vs_shared_table(per_seed: pd.DataFrame) -> pd.DataFrame:
    """Per env, method and quantity: shared and own (mean, std over seeds) and own - shared over paired seeds."""
    columns = ["env", "method", "quantity", "shared", "shared_std", "own", "own_std", "own_minus_shared",
               "difference_std", "n_seeds"]
    if per_seed.empty:
        return pd.DataFrame(columns=columns)
    wide = per_seed.pivot_table(index=["env", "method", "quantity", "seed"], columns="assignment", values="value",
                                aggfunc="first").reset_index()
    wide = wide.dropna(subset=[a for a in ASSIGNMENTS if a in wide.columns])
    if not set(ASSIGNMENTS) <= set(wide.columns) or wide.empty:
        return pd.DataFrame(columns=columns)
    wide["own_minus_shared"] = wide["own"] - wide["shared"]
    out = wide.groupby(["env", "method", "quantity"], sort=False).agg(
        shared=("shared", "mean"), shared_std=("shared", "std"), own=("own", "mean"), own_std=("own", "std"),
        own_minus_shared=("own_minus_shared", "mean"), difference_std=("own_minus_shared", "std"),
        n_seeds=("seed", "count")).reset_index()
    order = {q: i for i, q in enumerate(QUANTITIES)}
    return out.sort_values("quantity", key=lambda q: q.map(order), kind="stable").reset_index(drop=True)[columns]


def own_vs_shared_display(table: pd.DataFrame) -> pd.DataFrame:
    """The table with 'mean ± std over seeds' cells (rewards with 1 decimal, AUROC with 2)."""
    def cell(mean: float, std: float, n_seeds: int, digits: int) -> str:
        if n_seeds < 2 or np.isnan(std):
            return f"{mean:.{digits}f}"
        return f"{mean:.{digits}f} {PLUS_MINUS} {std:.{digits}f}"

    rows = []
    for row in table.itertuples():
        digits = 1 if row.quantity.startswith("reward") else 2
        rows.append({"env": row.env, "method": row.method, "quantity": row.quantity,
                     "shared": cell(row.shared, row.shared_std, row.n_seeds, digits),
                     "own": cell(row.own, row.own_std, row.n_seeds, digits),
                     "own - shared": cell(row.own_minus_shared, row.difference_std, row.n_seeds, digits),
                     "seeds": row.n_seeds})
    return pd.DataFrame(rows, columns=["env", "method", "quantity", "shared", "own", "own - shared", "seeds"])


def own_vs_shared_figure(per_seed: pd.DataFrame) -> Figure:
    """One panel per quantity: each seed's value (dots) and the mean ± std over seeds, shared beside own."""
    quantities = [q for q in QUANTITIES if q in set(per_seed["quantity"])] or [QUANTITIES[0]]
    fig = Figure(figsize=(4.0 * len(quantities) + 1.2, 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(quantities), squeeze=False)[0]
    data = per_seed.assign(run=per_seed["env"].str.replace("-v5", "") + "\n" + per_seed["method"])
    runs = data[["env", "method", "run"]].drop_duplicates()  # one x order for every panel: env, then METHODS order
    runs = runs.assign(rank=runs["method"].map({m: i for i, m in enumerate(METHODS)}))
    order = list(runs.sort_values(["env", "rank"], kind="stable")["run"])
    for ax, quantity in zip(axes, quantities):
        sub = data[data["quantity"] == quantity]
        if sub.empty:
            ax.text(0.5, 0.5, "no complete pair yet", ha="center", va="center", transform=ax.transAxes)
        else:
            kw = dict(data=sub, x="run", y="value", hue="assignment", hue_order=list(ASSIGNMENTS), order=order, ax=ax)
            with seeded_jitter():
                sns.stripplot(dodge=True, alpha=0.6, size=5, legend=False, **kw)
            sns.pointplot(dodge=0.4, errorbar="sd", linestyle="none", markers="D", capsize=0.1, **kw)
        ax.set(title=quantity, xlabel="", ylabel=quantity.split(" ")[0])
        if ax is not axes[-1] and ax.get_legend() is not None:
            ax.get_legend().remove()
    return fig


def _spread_phrase(row) -> str:
    if row.n_seeds < 2:
        return "one seed, so no spread to compare it with"
    spread = max(row.shared_std, row.own_std)
    side = "larger than" if abs(row.own_minus_shared) > spread else "within"
    return f"{side} the larger std over seeds ({spread:.2f})"


def own_vs_shared_reading(table: pd.DataFrame) -> list[str]:
    """Sentences made only of the table's numbers: the change from shared to own per method, env and quantity,
    and the Ensemble's reward relative to Masksembles with each assignment."""
    if table.empty:
        return ["No shared/own pair is complete yet: the runs listed as missing above come first."]
    lines = []
    for row in table.itertuples():
        digits = 1 if row.quantity.startswith("reward") else 2
        lines.append(f"{row.env}, {row.method}, {row.quantity}: {row.shared:.{digits}f} with the shared buffer, "
                     f"{row.own:.{digits}f} with own (own - shared {row.own_minus_shared:+.{digits}f} over "
                     f"{row.n_seeds} paired seed(s), {_spread_phrase(row)}).")
    for (env_id, method), sub in table.groupby(["env", "method"], sort=False):
        cells = sub.set_index("quantity")
        if {QUANTITIES[0], QUANTITIES[2]} <= set(cells.index):
            combined, single = cells.loc[QUANTITIES[0]], cells.loc[QUANTITIES[2]]
            lines.append(f"{env_id}, {method}, combining the members (combined minus single-member deterministic "
                         f"reward): {combined['shared'] - single['shared']:+.1f} with the shared buffer, "
                         f"{combined['own'] - single['own']:+.1f} with own.")
    for env_id, sub in table.groupby("env", sort=False):
        reward = sub[sub["quantity"] == QUANTITIES[0]].set_index("method")
        if {"ensemble", "masksembles"} <= set(reward.index):
            ens, mask = reward.loc["ensemble"], reward.loc["masksembles"]
            lines.append(f"{env_id}: Ensemble minus Masksembles, deterministic reward: "
                         f"{ens['shared'] - mask['shared']:+.1f} when both use the shared buffer, "
                         f"{ens['own'] - mask['shared']:+.1f} for the own Ensemble against the shared Masksembles, "
                         f"{ens['own'] - mask['own']:+.1f} when both use own.")
    return lines
