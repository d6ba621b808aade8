"""Shaping result frames into the paper's tables (wide layouts, paper-vs-us comparisons).

Also the tables' intervals: each reward cell's and each AUROC cell's over seeds, and the
differences to the baseline (rewards) and to the member-free detectors (AUROC), paired exactly
where both sides share their seeds and resamples. Here only which numbers pair with which, and the
rows: the bootstraps and intervals themselves live in `scoring.statistics`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from paper_lib.measures.definitions import ALL_MEMBER_MEASURES
from paper_lib.reporting.tables import PLUS_MINUS
from paper_lib.scoring.statistics import (cell_rng, difference_ci, difference_mc_standard_error, mc_standard_error,
                                         seed_mean_ci, seed_mean_difference_ci, seed_means)

#: Names the paper's CSVs use for our Gymnasium ids.
PAPER_ENV_NAMES = {"HalfCheetah-v5": "HalfCheetah", "Ant-v5": "Ant", "Walker2d-v5": "Walker2d", "Swimmer-v5": "Swimmer",
                   "SeaquestNoFrameskip-v4": "Seaquest", "MsPacmanNoFrameskip-v4": "MsPacman",
                   "BerzerkNoFrameskip-v4": "Berzerk", "SpaceInvadersNoFrameskip-v4": "SpaceInvaders"}


def _ordered(df: pd.DataFrame, column: str, order: list[str]) -> pd.DataFrame:
    return df.assign(**{column: pd.Categorical(df[column], [o for o in order if o in set(df[column])], ordered=True)})


def reward_table(summary: pd.DataFrame, methods: list[str]) -> pd.DataFrame:
    """Rows: method x inference x action mode; columns: env; cells 'mean ± std'.

    Where cells rest on different numbers of seeds (a partly trained profile), each cell says
    how many: 'mean ± std (n=2)'.
    """
    cells = [f"{m:.1f} {PLUS_MINUS} {s:.1f}" for m, s in zip(summary["mean"], summary["std"])]
    if "n_seeds" in summary and summary["n_seeds"].nunique() > 1:
        cells = [f"{c} (n={n})" for c, n in zip(cells, summary["n_seeds"])]
    df = summary.assign(actions=np.where(summary["deterministic"], "deterministic", "sampled"), cell=cells)
    df = _ordered(df, "method", methods)
    wide = df.pivot_table(index=["method", "inference", "actions"], columns="env", values="cell", aggfunc="first",
                          observed=True)
    return wide.reset_index().rename_axis(columns=None)


def auroc_table(metrics: pd.DataFrame, methods: list[str], value: str = "auroc") -> pd.DataFrame:
    """Rows: method x measure; columns: env; cells: mean over seeds of `value` (Table 2 layout)."""
    df = _ordered(metrics, "method", methods)
    wide = df.pivot_table(index=["method", "measure"], columns="env", values=value, aggfunc="mean", observed=True)
    return wide.reset_index().rename_axis(columns=None)


#: Table 2's rows of the peer detectors scored in stages of their own: the sequence detectors
#: (`scoring.sequence_scores.SEQUENCE_DETECTORS`, the `sequence_score` stage) and PEDM (`scoring.transition_scores`,
#: the `pedm` stage), and what their cells say where they have no number: the run's stage has not run, or the env is
#: not one the detector scores.
SEQUENCE_ROWS = ("episode_mean", "window_forest")
PEER_ROWS = (*SEQUENCE_ROWS, "pedm")
NOT_SCORED = "not scored"
NOT_APPLICABLE = "n/a"


def auroc_table_with_sequences(metrics: pd.DataFrame, sequence_metrics: pd.DataFrame, methods: list[str],
                               sequence_envs: tuple[str, ...] | Mapping[str, tuple[str, ...]],
                               float_format: str = "%.2f", rows: tuple[str, ...] = SEQUENCE_ROWS,
                               ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(Table 2 with a row per method for each peer detector of `rows`, the text its cells show: `save_table`'s
    cell_text).

    The other rows are `auroc_table(metrics, methods)`'s, unchanged. A detector's cell is the mean AUROC over the seeds
    of the cell whose stage has scored it (`sequence_metrics`: its rows of that detector, the same OOD set), and says
    "(k of n seeds)" where that is fewer than the cell's n seeds; NOT_SCORED where none has; NOT_APPLICABLE in an env
    outside `sequence_envs` (one tuple for every detector, or detector -> envs; Atari: pixel observations); NaN, as
    every row, where the method has no run in the env.
    """
    envs_of = sequence_envs if isinstance(sequence_envs, Mapping) else dict.fromkeys(rows, sequence_envs)
    table = auroc_table(metrics, methods)
    envs = [c for c in table.columns if c not in ("method", "measure")]
    seeds = metrics.groupby(["env", "method"])["seed"].nunique()
    scored = (sequence_metrics.groupby(["env", "method", "measure"])["auroc"].agg(["mean", "count"])
              if len(sequence_metrics) else pd.DataFrame(columns=["mean", "count"]))
    added, texts = [], []
    for method in dict.fromkeys(table["method"].astype(str)):
        for detector in rows:
            row, text = {"method": method, "measure": detector}, {"method": "", "measure": ""}
            for env in envs:
                n, (value, note) = int(seeds.get((env, method), 0)), (np.nan, "")
                if n and env not in envs_of[detector]:
                    note = NOT_APPLICABLE
                elif n and (env, method, detector) not in scored.index:
                    note = NOT_SCORED
                elif n:
                    value, k = scored.loc[(env, method, detector), ["mean", "count"]]
                    note = f"{float_format % value} ({int(k)} of {n} seeds)" if k < n else ""
                row[env], text[env] = value, note
            added.append(row)
            texts.append(text)
    order = {m: i for i, m in enumerate(methods)}
    full = pd.concat([table.assign(method=table["method"].astype(str)), pd.DataFrame(added)], ignore_index=True)
    full = full.assign(_order=full["method"].map(order)).sort_values(["_order", "measure"], kind="stable")
    # full.index still counts the rows as concatenated: the table's first, then the sequence rows in `texts`' order
    text = pd.DataFrame([texts[i - len(table)] if i >= len(table) else {c: "" for c in table.columns}
                         for i in full.index], columns=table.columns)
    return full.drop(columns="_order").reset_index(drop=True)[list(table.columns)], text


def sequence_note(peer_metrics: pd.DataFrame) -> str:
    """Table 2's caption on its peer-detector rows: the sequence detectors and PEDM (`PEER_ROWS`)."""
    def seeds(names: tuple[str, ...]) -> str:
        part = peer_metrics[peer_metrics["measure"].isin(names)] if len(peer_metrics) else peer_metrics
        return seeds_per_cell(part, ["env", "method", "measure"]) if len(part) else "no run yet"

    return (f"episode_mean and window_forest: the DEEDEE-style running episode mean and the DEXTER-style window "
            f"forest (causal), fit on the ID fit episodes and scored on the same states as every other row, each state "
            f"from its episode's kept states up to it (`sequence_score` stage; {seeds(SEQUENCE_ROWS)}). pedm: PEDM's "
            "probabilistic dynamics ensemble, fit on 50 ID episodes the agent plays in the `pedm` stage, scoring one "
            "simulated transition from each of the same states (the state its observation describes, under its own "
            "physics, the agent's deterministic action; `ood.transitions`) "
            f"({seeds(('pedm',))}); '{NOT_APPLICABLE}' in Walker2d, whose observation clips velocities and so does "
            "not determine the state, and in Atari. "
            f"'{NOT_SCORED}': the stage has not run for the cell's runs; '{NOT_APPLICABLE}' for every peer row in "
            "Atari (pixel observations).")


def read_reported(folder: str | Path, name: str) -> pd.DataFrame:
    """One of the paper's reported tables (data/paper_reported/reported_<name>.csv), in long form."""
    path = Path(folder) / f"reported_{name}.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing; it is transcribed from the paper (arXiv 2210.03649) and committed with the project")
    df = pd.read_csv(path)
    id_cols = [c for c in df.columns if c not in PAPER_ENV_NAMES.values()]
    long = df.melt(id_vars=id_cols, var_name="paper_env", value_name="paper").dropna(subset=["paper"])
    inverse = {v: k for k, v in PAPER_ENV_NAMES.items()}
    return long.assign(env=long["paper_env"].map(inverse)).drop(columns="paper_env")


def compare_with_paper(ours: pd.DataFrame, reported: pd.DataFrame, keys: list[str], value: str) -> pd.DataFrame:
    """Our `value` beside the paper's for every key both have, with the difference (ours - paper)."""
    merged = ours.rename(columns={value: "ours"}).merge(reported, on=[*keys, "env"], how="inner")
    return merged.assign(difference=merged["ours"] - merged["paper"])[[*keys, "env", "ours", "paper", "difference"]]


def seeds_per_cell(df: pd.DataFrame, cell: list[str], seed: str = "seed") -> str:
    """How many seeds stand behind each table cell: '1 seed per cell', or per env when cells differ.

    A partly trained profile (some seeds missing) gives cells with different counts; the
    caption says so instead of implying every cell has the profile's seeds.
    """
    counts = df.groupby(cell, observed=True)[seed].nunique()
    if counts.empty:
        return "no seeds"
    low, high = int(counts.min()), int(counts.max())
    if low == high:
        return f"{low} seed{'s' if low != 1 else ''} per cell"
    if "env" in cell:
        per_env = counts.groupby(level="env", sort=False).agg(["min", "max"])
        parts = [f"{env} {lo}" if lo == hi else f"{env} {lo} to {hi}" for env, (lo, hi) in per_env.iterrows()]
        return "seeds per cell: " + ", ".join(parts)
    return f"{low} to {high} seeds per cell"


def coverage(cfg, runs: list[tuple[str, str, int]], methods: list[str] | None = None) -> str:
    """'profile 'cpu': all 10 runs' or '... 7 of its 10 runs (missing ones: results/cpu/runs.md)'.

    `methods` narrows the profile's runs to those methods (e.g. the member methods a figure shows).
    """
    total = len([run for run in cfg.runs() if methods is None or run[1] in methods])
    what = "runs" if methods is None else f"{', '.join(methods)} runs"
    if len(runs) == total:
        return f"profile '{cfg.profile}': all {total} {what}"
    return (f"profile '{cfg.profile}': {len(runs)} of its {total} {what} (the missing ones are listed in "
            f"results/{cfg.profile}/runs.md)")


def caption(cfg, runs: list[tuple[str, str, int]], seeds: str, *details: str) -> str:
    """The parenthesis every table caption ends with: which runs, how many seeds per cell, the budget."""
    return "; ".join([coverage(cfg, runs), seeds, f"{cfg.steps_caption()} training steps per run", *details, "the paper used 3 seeds"])


def _span(values: pd.Series) -> str:
    low, high = int(values.min()), int(values.max())
    return f"{low}" if low == high else f"{low} to {high}"


#: How `protocol_note` names the collection protocols recorded in the datasets.
PROTOCOL_NAMES = {"main": "main-text protocol (section 5)", "appendix": "appendix G protocol",
                  "atari_head": "Atari-HEAD human play as OOD (a trial per configuration)"}


def protocol_note(metrics: pd.DataFrame) -> str:
    """How the scored states were collected, read from the per-run metrics (the datasets' own record).

    params.yaml may ask for another protocol than the committed datasets were collected with (until
    they are collected again); a caption must describe the states it rests on.
    """
    rows = metrics[metrics["ood_set"] == "perturbed"].drop_duplicates(["env", "method", "seed"])
    if rows.empty or not {"protocol", "n_ood", "n_ood_clusters", "n_id", "n_id_clusters"} <= set(rows.columns):
        return "collection protocol not recorded"
    parts = []
    for (name, actions), g in rows.groupby(["protocol", rows.get("actions", "actions unknown")], sort=False):
        parts.append(f"{PROTOCOL_NAMES.get(name, str(name))} with {actions} for {len(g)} run{'s' if len(g) != 1 else ''}: "
                     f"{_span(g['n_ood'])} OOD states from {_conditions(g)} and "
                     f"{_span(g['n_id'])} held-out ID states from {_span(g['n_id_clusters'])} episodes per run")
    return "states as collected: " + "; ".join(parts)


def _conditions(rows: pd.DataFrame) -> str:
    """'50 distinct conditions', or per env where they differ ('distinct conditions per env (A 50, B 3)').

    n_ood_clusters of a perturbed set counts distinct OOD conditions (identical configurations are
    one cluster), so a reader sees that MsPacman's interval rests on 3 mazes, not 50 draws.
    """
    if rows["n_ood_clusters"].nunique() == 1:
        return f"{_span(rows['n_ood_clusters'])} distinct conditions"
    per_env = rows.groupby("env", sort=True)["n_ood_clusters"].agg(_span)
    return "distinct conditions per env (" + ", ".join(f"{env} {n}" for env, n in per_env.items()) + ")"


# ----------------------------------------------------------------------------- intervals and differences


#: The columns that identify a reward cell (rewards_long's rows).
REWARD_KEYS = ["env", "method", "inference", "deterministic"]


def _seed_rewards(cell: pd.DataFrame) -> list[np.ndarray]:
    return [g["reward"].to_numpy(dtype=float) for _, g in cell.groupby("seed", sort=True)]


def reward_intervals(episodes: pd.DataFrame, n_boot: int, seed: int = 0, level: float = 0.95) -> pd.DataFrame:
    """Per reward cell, an interval of its mean (the mean over seeds of each seed's episode mean).

    Two-level bootstrap: resample the seeds, then the episodes within each drawn seed, never
    narrower than Student's t over the seed means (`statistics.seed_mean_ci`); with one seed, the
    episodes of that one run only. Seeded per cell (`statistics.cell_rng`).
    """
    rows = []
    for key, cell in episodes.groupby(REWARD_KEYS, sort=False):
        rewards = _seed_rewards(cell)
        low, high = seed_mean_ci(rewards, cell_rng(seed, *key), n_boot, level)
        rows.append({**dict(zip(REWARD_KEYS, key)), "ci_low": low, "ci_high": high,
                     "ci_over": "seeds, then episodes" if len(rewards) > 1 else "episodes"})
    return pd.DataFrame(rows)


def episode_slots(cell: pd.DataFrame) -> pd.MultiIndex:
    """(seed, env stream, position) of each evaluation episode: which seeded env played it, and when.

    `evaluation.evaluate_rewards` gives each member that plays its own env (seeded 10000 + seed +
    1000 m; combined inference and the baseline play one env, m = 0) and that env plays its
    episodes in order, its resets drawing from the env's own generator (MuJoCo's steps draw
    nothing from it). Two episodes with the same slot start from the same state whatever the
    policy, so the episodes of two runs can be paired slot by slot.
    """
    stream = cell["member"].fillna(0).astype(int) if "member" in cell else pd.Series(0, index=cell.index)
    position = cell.groupby([cell["seed"], stream], sort=False).cumcount()
    return pd.MultiIndex.from_arrays([cell["seed"], stream, position], names=["seed", "stream", "position"])


def _paired_rewards(cell: pd.DataFrame, base: pd.DataFrame) -> tuple[list[np.ndarray], list[np.ndarray]] | None:
    """Per seed, the cell's and the baseline's rewards slot by slot (two lists); None if the slots differ."""
    a = cell.set_index(episode_slots(cell))["reward"].sort_index()
    b = base.set_index(episode_slots(base))["reward"].sort_index()
    if not a.index.equals(b.index):
        return None
    seeds = a.index.get_level_values("seed")
    order = pd.unique(seeds)
    return [a[seeds == s].to_numpy(float) for s in order], [b[seeds == s].to_numpy(float) for s in order]


def reward_difference(cell: pd.DataFrame, base: pd.DataFrame, rng: np.random.Generator, n_boot: int,
                      level: float = 0.95) -> dict[str, float | int | str]:
    """mean(cell) - mean(base), each the mean over seeds of episode means, with its bootstrap interval.

    Paired (the same seed and episode draws for both) where both played the same episode slots
    (`episode_slots`); otherwise each side is resampled on its own ("unpaired").
    """
    rewards_a, rewards_b = _seed_rewards(cell), _seed_rewards(base)
    means_a, means_b = seed_means(rewards_a), seed_means(rewards_b)
    difference = means_a.mean() - means_b.mean()
    pairs = _paired_rewards(cell, base)
    if pairs is not None:
        low, high = seed_mean_difference_ci(*pairs, rng, "paired", n_boot, level)
    else:
        low, high = seed_mean_difference_ci(rewards_a, rewards_b, rng, "unpaired", n_boot, level)
    return {"difference": float(difference), "ci_low": low, "ci_high": high, "baseline": float(means_b.mean()),
            "pairing": "paired" if pairs is not None else "unpaired", "n_seeds": int(cell["seed"].nunique()),
            "n_episodes": len(cell), "baseline_seeds": int(base["seed"].nunique()), "baseline_episodes": len(base)}


#: The columns of `reward_vs_baseline` (also those of an empty result, e.g. a profile without a baseline run).
REWARD_DIFFERENCE_COLUMNS = ["env", "method", "inference", "actions", "difference", "ci_low", "ci_high", "baseline",
                             "pairing",
                             "n_seeds", "n_episodes", "baseline_seeds", "baseline_episodes"]


def reward_vs_baseline(episodes: pd.DataFrame, methods: list[str], n_boot: int, seed: int = 0,
                       level: float = 0.95) -> pd.DataFrame:
    """Long form: each member method's reward cell minus the baseline's (same env and action mode).

    The baseline plays single inference only, so every inference of a method is compared with it.
    Envs without a baseline run have no rows.
    """
    rows = []
    for (env, deterministic), group in episodes.groupby(["env", "deterministic"], sort=False):
        base = group[group["method"] == "baseline"]
        if base.empty:
            continue
        for (method, inference), cell in group[group["method"] != "baseline"].groupby(["method", "inference"], sort=False):
            rng = cell_rng(seed, env, method, inference, deterministic)
            rows.append({"env": env, "method": method, "inference": inference,
                         "actions": "deterministic" if deterministic else "sampled",
                         **reward_difference(cell, base, rng, n_boot, level)})
    long = pd.DataFrame(rows, columns=REWARD_DIFFERENCE_COLUMNS)
    long = _ordered(_ordered(long, "env", list(pd.unique(long["env"]))), "method", methods)
    return long.sort_values(["env", "method", "inference"], kind="stable").reset_index(drop=True)


def reward_difference_table(long: pd.DataFrame) -> pd.DataFrame:
    """`reward_vs_baseline` with sampled actions first (the paper's Table 1 protocol) and deterministic beside."""
    keys = ["env", "method", "inference"]
    parts = []
    for actions in ("sampled", "deterministic"):
        part = long[long["actions"] == actions].set_index(keys)[["difference", "ci_low", "ci_high", "baseline"]]
        parts.append(part.add_prefix(f"{actions} "))
    pairing = long.groupby(keys, observed=True, sort=False)["pairing"].agg(lambda p: " / ".join(pd.unique(p)))
    counts = long.groupby(keys, observed=True, sort=False)[["n_seeds", "n_episodes"]].max()
    wide = pd.concat([*parts, pairing, counts], axis=1).reset_index()
    return wide.sort_values(keys, kind="stable").reset_index(drop=True)


def reward_pairing_note(long: pd.DataFrame) -> str:
    """Which rows are paired and why, for the caption (from the table's own pairing column)."""
    why = {"paired": "the same seeds and episode indices drawn for both sides, since episode i of the method and of "
                     "the baseline started from the same seeded env (10000 + seed)",
           "unpaired": "each side resampled on its own, since their episodes came from other seeded envs (member m "
                       "of a single-member row plays in an env seeded 10000 + seed + 1000 m) or other seeds"}
    notes = []
    for pairing, rows in long.groupby("pairing", sort=True):
        inference = ", ".join(sorted(pd.unique(rows["inference"])))
        n_rows = len(rows.drop_duplicates(["env", "method", "inference"]))
        notes.append(f"{pairing} bootstrap for {inference} inference ({n_rows} rows): {why[pairing]}")
    return "; ".join(notes)


def _count(values: pd.Series, noun: str) -> str:
    span = _span(values)
    return f"{span} {noun}" + ("" if span == "1" else "s")


def counts_note(long: pd.DataFrame) -> str:
    """'each row: 1 seed, 10 episodes per action mode; the baseline: ...' (spans where rows differ)."""
    return (f"each row: {_count(long['n_seeds'], 'seed')}, {_count(long['n_episodes'], 'episode')} per action mode; "
            f"the baseline: {_count(long['baseline_seeds'], 'seed')}, {_count(long['baseline_episodes'], 'episode')}")


#: What makes two evaluation episodes the same game, as far as the episode files can tell.
GAME_KEYS = ["member", "reward", "length"]
#: One run playing in one action mode: the groups whose episodes `repeated_games` compares.
RUN_MODE_KEYS = ["env", "method", "seed", "inference", "deterministic"]


def repeated_games(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per run and action mode: how many of its evaluation episodes are distinct games (member, reward and length).

    Atari's NoFrameskip-v4 emulator has no sticky actions, and SB3's up to 30 no-op starts barely move some games'
    first state (MsPacman waits through its intro), so a deterministic policy can replay one game in every episode:
    its std over episodes is then 0 and its mean one game's score. Only groups with a repeated game are returned.
    """
    games = episodes.assign(member=episodes["member"].fillna(-1)) if "member" in episodes else episodes.assign(member=-1)
    counts = games.groupby(RUN_MODE_KEYS).apply(lambda g: pd.Series({"episodes": len(g),
                                                             "distinct_games": len(g[GAME_KEYS].drop_duplicates())}),
                                       include_groups=False).reset_index()
    counts["actions"] = np.where(counts.pop("deterministic"), "deterministic", "sampled")
    repeated = counts[counts["distinct_games"] < counts["episodes"]]
    return repeated[["env", "method", "seed", "inference", "actions", "episodes", "distinct_games"]].reset_index(drop=True)


def repeated_games_note(repeated: pd.DataFrame, episodes: pd.DataFrame) -> str:
    """One sentence: how many run x mode groups replay games, the fewest distinct ones, and which action modes."""
    groups = episodes.groupby(RUN_MODE_KEYS).ngroups
    if repeated.empty:
        return f"Every one of the {groups} run x mode groups played distinct games in all its episodes."
    fewest = repeated.sort_values("distinct_games", kind="stable").iloc[0]  # ties: the first listed, on any CPU
    modes = " and ".join(sorted(set(repeated["actions"])))
    return (f"{len(repeated)} of {groups} run x mode groups replayed a game ({modes} actions; envs: "
            f"{', '.join(dict.fromkeys(repeated['env']))}); the fewest: {fewest['env']} {fewest['method']} seed "
            f"{fewest['seed']}, {fewest['inference']} inference, {fewest['actions']} actions, {fewest['distinct_games']} "
            f"distinct game(s) in {fewest['episodes']} episodes. Such a cell's std is not a spread over games, and its "
            f"mean rests on fewer games than its episode count says.")


# ----------------------------------------------------------------------------- AUROC over seeds and against detectors

#: Measures that need the members (or, for max_prob and entropy, a discrete policy); the rest are member-free detectors.
#: The family of each member measure (value head or policy head), for `auroc_members_vs_baseline`.
MEASURE_FAMILIES = {"value_std": "value", "policy_std": "policy", "policy_js": "policy", "max_prob": "policy",
                    "entropy": "policy"}
#: Whether replicate i of two measures of one run comes from the same cluster resample. It does:
#: `scoring.ood_scores.score_run` gives every measure of an OOD set the same resampling seed (tested in
#: tests/reporting/test_table_statistics.py on the committed replicates), so differences between measures of
#: a run are paired.
REPLICATES_SHARE_RESAMPLES = True

Replicates = dict[tuple[str, str, int, str, str], np.ndarray]  # (env, method, seed, ood_set, measure) -> replicates


def pooled_auroc(metrics: pd.DataFrame, replicates: Replicates, n_boot: int, seed: int = 0,
                 level: float = 0.95) -> pd.DataFrame:
    """One row per (env, method, ood_set, measure) over its training seeds (`scoring.ood_scores.summarize_seeds`).

    AUROC mean and spread over seeds (auroc_seed_std), and a 95% CI that resamples seeds, then
    each seed's cluster-bootstrap replicates; seeded per cell (`cell_rng`).
    """
    from paper_lib.scoring.ood_scores import summarize_seeds

    group = ["env", "method", "ood_set", "measure"]
    parts = []
    for key, frame in metrics.groupby(group, sort=False):
        env, method, ood_set, measure = key
        reps = pd.concat([pd.DataFrame({"env": env, "method": method, "ood_set": ood_set, "measure": measure,
                                        "seed": s, "auroc": replicates[(env, method, s, ood_set, measure)]})
                          for s in frame["seed"]], ignore_index=True)
        parts.append(summarize_seeds(frame, reps, cell_rng(seed, *key), n_boot=n_boot, level=level))
    pooled = pd.concat(parts, ignore_index=True)
    counts = ["n_id", "n_ood", "n_id_clusters", "n_ood_clusters"]  # means over seeds: whole numbers where seeds agree
    whole = [c for c in counts if c in pooled and (pooled[c] % 1 == 0).all()]
    return pooled.astype({c: int for c in whole})


def _is_detector(measures: pd.Series) -> pd.Series:
    return ~measures.isin(ALL_MEMBER_MEASURES)


def best_detectors(metrics: pd.DataFrame) -> pd.Series:
    """Per (env, ood_set), the member-free detector with the highest AUROC averaged over every run of that env."""
    free = metrics[_is_detector(metrics["measure"])]
    means = free.groupby(["env", "ood_set", "measure"], sort=False)["auroc"].mean()
    return means.groupby(level=["env", "ood_set"], sort=False).idxmax().map(lambda key: key[-1])


def _seed_aurocs(metrics: pd.DataFrame, env: str, method: str, ood_set: str, measure: str) -> pd.Series:
    rows = metrics[(metrics["env"] == env) & (metrics["method"] == method) & (metrics["ood_set"] == ood_set)
                   & (metrics["measure"] == measure)]
    return rows.set_index("seed")["auroc"].sort_index()


def _seed_mc_se(metrics: pd.DataFrame, env: str, method: str, ood_set: str, measure: str, seeds: pd.Index) -> float:
    """The MC standard error of the mean AUROC over `seeds` (`statistics.mc_standard_error`); NaN where the metrics
    do not carry their scoring spread."""
    if not {"auroc_scoring_std", "n_scoring_seeds"} <= set(metrics.columns) or len(seeds) == 0:
        return np.nan
    rows = metrics[(metrics["env"] == env) & (metrics["method"] == method) & (metrics["ood_set"] == ood_set)
                   & (metrics["measure"] == measure)].set_index("seed").loc[seeds]
    return mc_standard_error(rows["auroc_scoring_std"], rows["n_scoring_seeds"])


def _auroc_difference(a: pd.Series, b: pd.Series, reps_a: list[np.ndarray], reps_b: list[np.ndarray],
                      rng: np.random.Generator, pairing: str, n_boot: int, level: float) -> dict[str, float]:
    low, high = difference_ci(reps_a, reps_b, rng, pairing, n_boot, level, estimates_a=a.to_numpy(),
                              estimates_b=b.to_numpy())
    return {"difference": float(a.mean() - b.mean()), "ci_low": low, "ci_high": high}


def _mc_errors(se_a: float, se_b: float, a: str, b: str) -> dict[str, float]:
    """The `<column>_mc_se` columns of a difference row (`reporting.tables.save_table` prints each column to the
    digits its MC noise supports)."""
    return {f"{a}_mc_se": se_a, f"{b}_mc_se": se_b, "difference_mc_se": difference_mc_standard_error(se_a, se_b)}


#: The columns of `auroc_vs_detectors` and `auroc_members_vs_baseline` (also of an empty result).
DETECTOR_DIFFERENCE_COLUMNS = ["env", "ood_set", "method", "measure", "auroc", "detector", "detector_auroc",
                               "difference", "ci_low", "ci_high", "family_size", "family_ci_low", "family_ci_high",
                               "pairing", "n_seeds", "auroc_mc_se", "detector_auroc_mc_se", "difference_mc_se"]
BASELINE_DIFFERENCE_COLUMNS = ["env", "ood_set", "method", "family", "measure", "auroc", "baseline_detector",
                               "baseline_auroc", "difference", "ci_low", "ci_high", "pairing", "n_seeds",
                               "baseline_seeds", "auroc_mc_se", "baseline_auroc_mc_se", "difference_mc_se"]


def auroc_vs_detectors(metrics: pd.DataFrame, replicates: Replicates, methods: list[str], n_boot: int, seed: int = 0,
                       level: float = 0.95) -> pd.DataFrame:
    """Each member measure's AUROC minus its own runs' best member-free detector (`best_detectors`), per seed.

    The same runs and states on both sides: seeds are drawn once for both; the cluster resamples
    are shared only where the replicates share them (`REPLICATES_SHARE_RESAMPLES`). Beside each cell's interval,
    its simultaneous one over the `family_size` cells of its (env, OOD set) (Bonferroni: level 1 - (1 - level) / m,
    from the same draws): "some cell beats the detector" needs it, or m chances would each risk 1 - level.
    """
    pairing = "paired" if REPLICATES_SHARE_RESAMPLES else "seeds"
    best = best_detectors(metrics)
    rows = []
    members = metrics[~_is_detector(metrics["measure"])]
    cells = [key for key, _ in members.groupby(["env", "ood_set", "method", "measure"], sort=False)
             if (key[0], key[1]) in best]
    family_size = pd.Series([(env, ood_set) for env, ood_set, _, _ in cells]).value_counts().to_dict()
    for env, ood_set, method, measure in cells:
        detector = best[(env, ood_set)]
        a, b = _seed_aurocs(metrics, env, method, ood_set, measure), _seed_aurocs(metrics, env, method, ood_set, detector)
        seeds = a.index.intersection(b.index)
        a, b = a[seeds], b[seeds]
        reps_a = [replicates[(env, method, s, ood_set, measure)] for s in seeds]
        reps_b = [replicates[(env, method, s, ood_set, detector)] for s in seeds]
        m = family_size[(env, ood_set)]
        family = _auroc_difference(a, b, reps_a, reps_b, cell_rng(seed, env, ood_set, method, measure, detector),
                                   pairing, n_boot, 1.0 - (1.0 - level) / m)
        rng = cell_rng(seed, env, ood_set, method, measure, detector)
        rows.append({"env": env, "ood_set": ood_set, "method": method, "measure": measure, "auroc": a.mean(),
                     "detector": detector, "detector_auroc": b.mean(),
                     **_auroc_difference(a, b, reps_a, reps_b, rng, pairing, n_boot, level),
                     "family_size": m, "family_ci_low": family["ci_low"], "family_ci_high": family["ci_high"],
                     "pairing": "paired" if pairing == "paired" else "unpaired", "n_seeds": len(seeds),
                     **_mc_errors(_seed_mc_se(metrics, env, method, ood_set, measure, seeds),
                                  _seed_mc_se(metrics, env, method, ood_set, detector, seeds), "auroc", "detector_auroc")})
    return _sorted_auroc_rows(pd.DataFrame(rows, columns=DETECTOR_DIFFERENCE_COLUMNS), methods,
                              ["env", "ood_set", "method", "measure"])


def detector_pairing_note(frame: pd.DataFrame) -> str:
    """How `auroc_vs_detectors`' intervals pair the two sides, from its pairing column, for the caption."""
    if set(frame["pairing"]) == {"paired"}:
        return "paired: the same seeds and the same cluster resamples on both sides"
    return ("seeds drawn once for both sides (the same runs), cluster resamples independent, since the score stage "
            "draws each measure's replicates from its own resamples: unpaired within a run")


def _sorted_auroc_rows(df: pd.DataFrame, methods: list[str], keys: list[str]) -> pd.DataFrame:
    df = _ordered(_ordered(df, "env", list(pd.unique(df["env"]))), "method", methods)
    df = _ordered(df, "ood_set", ["perturbed", "noise", *sorted(set(df["ood_set"]) - {"perturbed", "noise"})])
    return df.sort_values(keys, kind="stable").reset_index(drop=True)


def auroc_members_vs_baseline(metrics: pd.DataFrame, replicates: Replicates, methods: list[str], n_boot: int,
                              seed: int = 0, level: float = 0.95) -> pd.DataFrame:
    """Per env, OOD set, method and measure family: its best member measure minus the baseline's best detector.

    Two different agents on their own states: the interval is unpaired (each side resampled on
    its own, seeds included). Both "best" are picked on these same data, so both are optimistic.
    """
    rows = []
    for (env, ood_set), group in metrics.groupby(["env", "ood_set"], sort=False):
        base = group[(group["method"] == "baseline") & _is_detector(group["measure"])]
        if base.empty:
            continue
        detector = base.groupby("measure")["auroc"].mean().idxmax()
        b = _seed_aurocs(metrics, env, "baseline", ood_set, detector)
        reps_b = [replicates[(env, "baseline", s, ood_set, detector)] for s in b.index]
        members = group[(group["method"] != "baseline") & ~_is_detector(group["measure"])]
        for (method, family), cells in members.groupby(["method", members["measure"].map(MEASURE_FAMILIES)], sort=False):
            measure = cells.groupby("measure")["auroc"].mean().idxmax()
            a = _seed_aurocs(metrics, env, method, ood_set, measure)
            reps_a = [replicates[(env, method, s, ood_set, measure)] for s in a.index]
            rng = cell_rng(seed, env, ood_set, method, family, measure, detector)
            rows.append({"env": env, "ood_set": ood_set, "method": method, "family": family, "measure": measure,
                         "auroc": a.mean(), "baseline_detector": detector, "baseline_auroc": b.mean(),
                         **_auroc_difference(a, b, reps_a, reps_b, rng, "unpaired", n_boot, level),
                         "pairing": "unpaired", "n_seeds": len(a), "baseline_seeds": len(b),
                         **_mc_errors(_seed_mc_se(metrics, env, method, ood_set, measure, a.index),
                                      _seed_mc_se(metrics, env, "baseline", ood_set, detector, b.index),
                                      "auroc", "baseline_auroc")})
    return _sorted_auroc_rows(pd.DataFrame(rows, columns=BASELINE_DIFFERENCE_COLUMNS), methods,
                              ["env", "ood_set", "method", "family"])


#: The columns of `auroc_between_methods` (also of an empty result).
PAIRWISE_COLUMNS = ["env", "ood_set", "measure", "method", "versus", "auroc", "versus_auroc", "difference", "ci_low",
                    "ci_high", "family_size", "family_ci_low", "family_ci_high", "pairing", "states", "n_seeds",
                    "auroc_mc_se", "versus_auroc_mc_se", "difference_mc_se"]


def auroc_between_methods(metrics: pd.DataFrame, replicates: Replicates, pairs: list[tuple[str, str]],
                          measures: tuple[str, ...], n_boot: int, seed: int = 0, ood_set: str = "perturbed",
                          level: float = 0.95, states: str = "own") -> pd.DataFrame:
    """For each env and measure, AUROC(method) - AUROC(versus) over the seeds both have, with its interval.

    `states="own"`: two agents, each on the states it collected: seed s of one is compared with seed s of the
    other (seeds drawn once for both), cluster resamples independent ("seeds" pairing). `states="common"`: both
    scored the baseline's states of seed s (`pipeline.common_states`), drawn with the same cluster resamples, so
    replicate i of both comes from the same states ("paired"). Either way the interval is at least Student's t
    over the per-seed differences (`statistics.difference_ci`). Beside it, the simultaneous interval over the
    `family_size` pairs of its (env, measure) (Bonferroni, from the same draws), for a verdict that one pair of
    several is surely behind.
    """
    if states not in ("own", "common"):
        raise ValueError(f"states must be 'own' (each agent's) or 'common' (the baseline's), got {states!r}")
    pairing = "paired" if states == "common" else "seeds"
    rows = []
    cells = metrics[metrics["ood_set"] == ood_set]
    for env in pd.unique(cells["env"]):
        for measure in measures:
            seeds_of = {(method, versus): _seed_aurocs(metrics, env, method, ood_set, measure).index.intersection(
                _seed_aurocs(metrics, env, versus, ood_set, measure).index) for method, versus in pairs}
            family_size = sum(not seeds.empty for seeds in seeds_of.values())
            for method, versus in pairs:
                a, b = (_seed_aurocs(metrics, env, m, ood_set, measure) for m in (method, versus))
                seeds = seeds_of[(method, versus)]
                if seeds.empty:
                    continue
                a, b = a[seeds], b[seeds]
                reps_a = [replicates[(env, method, s, ood_set, measure)] for s in seeds]
                reps_b = [replicates[(env, versus, s, ood_set, measure)] for s in seeds]
                family = _auroc_difference(a, b, reps_a, reps_b, cell_rng(seed, env, ood_set, measure, method, versus),
                                           pairing, n_boot, 1.0 - (1.0 - level) / family_size)
                rng = cell_rng(seed, env, ood_set, measure, method, versus)
                rows.append({"env": env, "ood_set": ood_set, "measure": measure, "method": method, "versus": versus,
                             "auroc": a.mean(), "versus_auroc": b.mean(),
                             **_auroc_difference(a, b, reps_a, reps_b, rng, pairing, n_boot, level),
                             "family_size": family_size, "family_ci_low": family["ci_low"],
                             "family_ci_high": family["ci_high"],
                             "pairing": pairing, "states": states, "n_seeds": len(seeds),
                             **_mc_errors(_seed_mc_se(metrics, env, method, ood_set, measure, seeds),
                                          _seed_mc_se(metrics, env, versus, ood_set, measure, seeds),
                                          "auroc", "versus_auroc")})
    return pd.DataFrame(rows, columns=PAIRWISE_COLUMNS)


def ci_verdicts(df: pd.DataFrame) -> dict[str, int]:
    """How many rows' intervals lie above 0, below 0, or contain it."""
    above, below = int((df["ci_low"] > 0).sum()), int((df["ci_high"] < 0).sum())
    return {"above": above, "below": below, "undecided": len(df) - above - below}


#: A raw-input detector at or above this AUROC means the OOD states differ from the ID ones in the input itself, so
#: plainly that no uncertainty is needed to tell them apart: such an OOD set tests little of a member measure.
TRIVIAL_AUROC = 0.99
RAW_INPUT_DETECTORS = ("knn_obs", "mahalanobis_obs")
TRIVIAL_COLUMNS = ["env", "ood_set", "method", "detector", "auroc", "n_seeds", "trivially_separable"]


def trivially_separable(metrics: pd.DataFrame, threshold: float = TRIVIAL_AUROC) -> pd.DataFrame:
    """Per env, OOD set and method: the raw-input detector (kNN or Mahalanobis on observations or pixels) with the
    highest AUROC (mean over seeds), and whether it reaches `threshold`."""
    raw = metrics[metrics["measure"].isin(RAW_INPUT_DETECTORS)]
    cells = raw.groupby(["env", "ood_set", "method", "measure"], sort=False).agg(auroc=("auroc", "mean"),
                                                                                 n_seeds=("seed", "nunique"))
    best = cells.reset_index().sort_values("auroc", ascending=False, kind="stable")
    best = best.drop_duplicates(["env", "ood_set", "method"]).rename(columns={"measure": "detector"})
    order = {key: i for i, key in enumerate(dict.fromkeys(zip(raw["env"], raw["ood_set"], raw["method"])))}
    best = best.assign(trivially_separable=best["auroc"] >= threshold,
                       _order=[order[key] for key in zip(best["env"], best["ood_set"], best["method"])])
    return best.sort_values("_order")[TRIVIAL_COLUMNS].reset_index(drop=True)


def trivially_separable_note(table: pd.DataFrame, threshold: float = TRIVIAL_AUROC) -> str:
    """One line per env and OOD set whose raw-input detectors separate every method's states at `threshold`."""
    flagged = table[table["trivially_separable"]]
    if flagged.empty:
        return f"No OOD set is trivially separable: no raw-input detector reaches AUROC {threshold:.2f} on any run's states."
    lines = []
    for (env, ood_set), group in flagged.groupby(["env", "ood_set"], sort=False):
        total = int(((table["env"] == env) & (table["ood_set"] == ood_set)).sum())
        lines.append(f"- **{env}**, {ood_set} states: a raw-input detector reaches AUROC >= {threshold:.2f} for "
                     f"{len(group)} of {total} methods' states (best {group['auroc'].max():.3f}): these OOD states "
                     "differ plainly in the input, so they test little of what a member measure adds.")
    return "\n".join(lines)
