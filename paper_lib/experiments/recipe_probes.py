"""The recipe probes: short training runs that settled the agent recipe before the long matrices.

Each probe is an ordinary training run (`python -m paper_lib.agents.training ... --hp KEY=VALUE`, commands in
`scripts/recipe_probes.q`) written to results/recipe_probes/<env>/<variant>/seed<N>. This module
turns them into the table that docs/deviations.md quotes: training reward along the
way (sampled actions, Monitor's last 100 episodes) and the final agent's evaluation reward.

    python -m paper_lib.experiments.recipe_probes results/recipe_probes \
        --extra Swimmer-v5/baseline-sb3-defaults=results/cpu/checkpoints/Swimmer-v5/baseline/seed0

Rows already in results/recipe_probes/summary.csv whose run has not changed (same probe, seed and steps) are
kept as they are: a probe is evaluated once, on the machine that trained it, and a later summary neither
re-steps its episodes (MuJoCo's last bits differ between CPUs) nor loses rows whose folders have gone (the
Swimmer `previous-recipe-*` rows, `--extra` runs since replaced). `--fresh` evaluates every run again.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
import torch as th

from paper_lib.agents.checkpoints import load_checkpoint
from paper_lib.reporting.tables import save_table
from paper_lib.scoring.rewards import evaluate_rewards

#: Training steps at which the table reads the training curve.
MARKS = (100_000, 200_000, 300_000, 500_000, 1_000_000, 2_000_000)


def probe_row(name: str, folder: Path, episodes: int, seed: int) -> dict:
    """Curve readings and evaluation reward of one probe run."""
    ckpt = load_checkpoint(folder)
    config, curve = ckpt.config, ckpt.training_curve()
    row = {"probe": name, "seed": int(config["seed"]), "method": config["method"],
           "steps": int(curve["timesteps"].iloc[-1]),
           "dropout_p": config.get("dropout_p"), "masksembles_scale": config.get("masksembles_scale"),
           "policy": str(config.get("policy") or "SB3 defaults"), "normalize_obs": config.get("normalize_obs"),
           "normalize_reward": bool(config.get("normalize_reward", False)),
           "wall_minutes": round(config.get("wall_seconds", float("nan")) / 60, 1)}
    for mark in MARKS:
        if curve["timesteps"].iloc[-1] >= mark:
            # mean of the training reward over the rollouts ending in the last 5% of steps before the mark
            window = curve[(curve.timesteps <= mark) & (curve.timesteps > 0.95 * mark)]
            row[f"train@{mark // 1000}k"] = float(window["reward"].mean())
    th.manual_seed(seed)
    episodes_df = evaluate_rewards(ckpt, episodes, seed)
    combined = episodes_df[episodes_df.inference == ("combined" if "combined" in set(episodes_df.inference) else "single")]
    for deterministic, label in ((True, "eval_deterministic"), (False, "eval_sampled")):
        row[label] = float(combined.loc[combined.deterministic == deterministic, "reward"].mean())
    return row


def ratio_clip_share(folder: Path, n_states: int = 400, clip_range: float = 0.1, seed: int = 0,
                     log_stds: tuple[float | None, ...] = (None, -1.0, 0.0)) -> pd.DataFrame:
    """How much of a shared-buffer minibatch PPO's clipping silences, at several action stds.

    Under the paper's shared buffer, member j is updated on transitions member i collected, with
    the ratio pi_j(a|s) / pi_i(a|s). For states the agent visits (sampled play, one episode), draw
    each member's action around its mean and count the member pairs (i != j; for MC methods also
    i == j, whose masks are redrawn) whose ratio falls outside [1 - clip, 1 + clip]. `None` is the
    agent's own learned std; the other rows replace it by exp(log_std) with the same means.
    """
    from paper_lib.agents.envs import make_env
    from paper_lib.methods.policy import MemberActorCriticPolicy

    ckpt = load_checkpoint(folder)
    policy = ckpt.model.policy
    if not isinstance(policy, MemberActorCriticPolicy):
        raise ValueError(f"{folder} holds a baseline: the clip share needs members")
    th.manual_seed(seed)
    env = make_env(ckpt.config["env_id"], 1, seed)
    obs, states = env.reset(), []
    for _ in range(n_states):
        states.append(obs[0].copy())
        action, _ = ckpt.model.predict(obs, deterministic=False)
        obs, *_ = env.step(action)
    observations = th.as_tensor(np.asarray(states), dtype=th.float32)
    with th.no_grad():
        acting, _ = policy.member_outputs_from_tensor(observations)  # the rollout's means
        updating, _ = policy.member_outputs_from_tensor(observations)  # MC methods: masks redrawn
        rows = []
        for log_std in log_stds:
            std = policy.log_std.exp() if log_std is None else th.full_like(policy.log_std, float(np.exp(log_std)))
            k = acting.shape[0]
            outside = np.zeros((k, k))
            for i in range(k):
                action = acting[i] + std * th.randn_like(acting[i])
                logp_old = th.distributions.Normal(acting[i], std).log_prob(action).sum(-1)
                for j in range(k):
                    logp_new = th.distributions.Normal(updating[j], std).log_prob(action).sum(-1)
                    outside[i, j] = float(((logp_new - logp_old).abs() > np.log1p(clip_range)).float().mean())
            rows.append({"std": "learned" if log_std is None else f"exp({log_std:g})",
                         "mean_std": float(std.mean()),
                         "cross_member_outside_clip": float(outside[~np.eye(k, dtype=bool)].mean()),
                         "same_member_outside_clip": float(np.diag(outside).mean())})
    return pd.DataFrame(rows)


def summarize(root: Path, extra: dict[str, Path], episodes: int = 5, seed: int = 0,
              known: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per probe run (every seed folder of every variant, and the extra folders).

    `known` (a previous summary) supplies the rows of runs that have not changed since (same probe, seed and
    steps) and of runs no longer on disk; only new or extended runs are evaluated.
    """
    runs = [(f"{p.parent.parent.name}/{p.parent.name}", p) for p in sorted(root.glob("*/*/seed*"))
            if (p / "config.json").is_file()]
    runs += sorted(extra.items())
    known = known if known is not None else pd.DataFrame(columns=["probe", "seed", "steps"])
    known_keys = {(r.probe, int(r.seed), int(r.steps)): i for i, r in known.iterrows()}
    rows, reused = [], set()
    for name, folder in runs:
        ckpt_key = (name, *_seed_and_steps(folder))
        if ckpt_key in known_keys:
            reused.add(known_keys[ckpt_key])
            rows.append(known.loc[known_keys[ckpt_key]].to_dict())
        else:
            rows.append(probe_row(name, folder, episodes, seed))
    on_disk = {name for name, _ in runs}
    # rows of runs whose folders are gone (and not replaced by a newer run of the same probe and seed)
    gone = [i for i, r in known.iterrows() if i not in reused and r.probe not in on_disk]
    rows += [known.loc[i].to_dict() for i in gone]
    df = pd.DataFrame(rows).sort_values(["probe", "seed"], kind="stable").reset_index(drop=True)
    marks = sorted((c for c in df.columns if c.startswith("train@")), key=lambda c: int(c[6:-1]))
    return df[["probe", "seed", "method", "steps", *marks, "eval_deterministic", "eval_sampled", "dropout_p",
               "masksembles_scale", "policy", "normalize_obs", "normalize_reward", "wall_minutes"]]


def _seed_and_steps(folder: Path) -> tuple[int, int]:
    """A run's seed and trained steps, from its config and training curve (no model is loaded)."""
    config = json.loads((folder / "config.json").read_text())
    steps = pd.read_csv(folder / "training_curve.csv", usecols=["timesteps"])["timesteps"].iloc[-1]
    return int(config["seed"]), int(steps)


def by_variant(df: pd.DataFrame) -> pd.DataFrame:
    """Mean over a variant's seeds of each reading, with the seed count and each seed's train@300k."""
    readings = [c for c in df.columns if c.startswith("train@")] + ["eval_deterministic", "eval_sampled"]
    grouped = df.groupby("probe", sort=True)
    out = grouped[readings].mean()
    out.insert(0, "seeds", grouped["seed"].count())
    if "train@300k" in df:
        out["train@300k per seed"] = grouped.apply(
            lambda g: " / ".join("-" if np.isnan(v) else f"{v:.0f}" for v in g.sort_values("seed")["train@300k"]),
            include_groups=False)
    return out.reset_index()


def main() -> None:
    parser = argparse.ArgumentParser(description="Summarize the recipe probes into results/recipe_probes/summary.*")
    parser.add_argument("root", type=Path)
    parser.add_argument("--clip-share", type=Path, action="append", default=[], metavar="FOLDER",
                        help="also measure the PPO clip share of a member probe (results/recipe_probes/clip_share.*)")
    parser.add_argument("--extra", action="append", default=[], metavar="NAME=FOLDER",
                        help="another checkpoint folder to compare (e.g. a run of the previous recipe)")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--fresh", action="store_true", help="evaluate every run again, ignoring summary.csv")
    args = parser.parse_args()
    th.set_num_threads(1)
    extra = {}
    for item in args.extra:
        name, sep, folder = item.partition("=")
        if not sep:
            parser.error(f"--extra {item!r}: write NAME=FOLDER")
        extra[name] = Path(folder)
    if args.clip_share:
        shares = pd.concat([ratio_clip_share(folder).assign(probe=f"{folder.parent.parent.name}/{folder.parent.name}")
                            for folder in args.clip_share], ignore_index=True)
        save_table(shares[["probe", *shares.columns[:-1]]], args.root / "clip_share",
                   "Share of PPO ratios outside the clip range (0.1) between members (cross) and for the acting member "
                   "re-evaluated with fresh masks (same), on 400 visited states, at the learned and at wider action "
                   "stds with the same member means.", float_format="%.2f")
        print(shares.to_string())
    previous = args.root / "summary.csv"
    known = None if args.fresh or not previous.is_file() else pd.read_csv(previous)
    df = summarize(args.root, extra, args.episodes, known=known)
    caption = (f"Recipe probes: training reward (sampled actions, mean of the Monitor's last-100-episode mean over the "
               f"last 5% of steps before each mark) and the final agent's reward over {args.episodes} evaluation "
               "episodes (combined inference), one row per run. Hints for choosing the recipe, not results.")
    save_table(df, args.root / "summary", caption, float_format="%.1f")
    variants = by_variant(df)
    save_table(variants, args.root / "summary_by_variant",
               "Recipe probes averaged over each variant's seeds (the readings of summary.md; per-seed training reward "
               "at 300k in the last column).", float_format="%.1f")
    print(variants.to_string(float_format=lambda v: f"{v:.1f}" if np.isfinite(v) else "-"))


if __name__ == "__main__":
    main()
