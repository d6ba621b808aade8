"""Does value uncertainty flag physically unstable states? The paper's Ant "levitation" at spawn.

Section 6 of the paper: "in Ant, value uncertainty also acts as a measure of physical instability,
particularly detachment from the floor, e.g. it explains substantial uncertainty at the beginning of
an episode when Ant is spawned". The OOD benchmark cannot test this: its ID states skip the first
steps of every episode. So this module plays each trained member-method agent from reset in its own
(unperturbed) env, scores every state it saw, and records whether the robot touched the floor there
(any MuJoCo contact with the geom named "floor"). Ant and Walker2d are spawned above the floor and
fall for a few steps; HalfCheetah starts on it, a control. Notebook 12 (the `spawn` stage) runs it on
every trained MuJoCo member-method run.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
import torch as th

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.agents.envs import is_atari
from paper_lib.experiments.kept_rows import fingerprint
from paper_lib.measures.estimates import uncertainty
from paper_lib.scoring.metrics import auroc

FLOOR = "floor"
MEASURES = ("value_std", "policy_std")
#: The columns of ``spawn_rollouts``' rows (after env, method, seed).
ROLLOUT_COLUMNS = ("episode", "step", *MEASURES, "floor_contacts", "airborne")


def floor_contacts(mujoco_env) -> int:
    """How many of the current MuJoCo contacts involve the floor geom (0: the robot is in the air)."""
    model, data = mujoco_env.unwrapped.model, mujoco_env.unwrapped.data
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, FLOOR)
    if floor < 0:
        raise ValueError(f"{mujoco_env.spec.id if mujoco_env.spec else mujoco_env} has no geom named {FLOOR!r}: "
                         "the spawn analysis needs a MuJoCo env with a floor (HalfCheetah, Ant, Walker2d, ...).")
    contacts = data.contact[: data.ncon]
    return int(np.sum((contacts.geom1 == floor) | (contacts.geom2 == floor)))


def spawn_rollouts(run: Checkpoint, episodes: int = 5, steps: int = 100, seed: int = 0) -> pd.DataFrame:
    """The first ``steps`` steps of ``episodes`` deterministic episodes from reset: uncertainty and floor contact.

    Episode i is reset with env seed ``seed + i``; torch is seeded with ``seed`` (the MC methods' masks),
    so the same seed gives the same rows. Each row is the state the agent acted on.
    """
    env_id, method = run.config["env_id"], run.config["method"]
    if is_atari(env_id) or method == "baseline":
        raise ValueError(f"{env_id} {method}: the spawn analysis needs a MuJoCo member-method run "
                         "(value_std needs members; floor contact needs MuJoCo).")
    if episodes < 1 or steps < 1:
        raise ValueError(f"episodes={episodes}, steps={steps}: both must be at least 1.")
    th.manual_seed(seed)
    venv = run.env(1, seed)
    mujoco_env = venv.unwrapped.envs[0]
    frames = []
    for episode in range(episodes):
        venv.seed(seed + episode)
        obs = venv.reset()
        seen, contacts = [], []
        for _ in range(steps):
            seen.append(obs[0])
            contacts.append(floor_contacts(mujoco_env))
            action, _ = run.model.predict(obs, deterministic=True)
            obs, _, done, _ = venv.step(action)
            if done[0]:
                break
        scores = uncertainty(run.model.policy, np.stack(seen), MEASURES, seed=seed + episode)
        frames.append(pd.DataFrame({"episode": episode, "step": np.arange(len(seen)), **scores,
                                    "floor_contacts": contacts}))
    rows = pd.concat(frames, ignore_index=True)
    return rows.assign(airborne=rows.floor_contacts == 0)


#: Part of each run's fingerprint (`kept_rows`): bump it when a change to this module should play every run again.
ROWS_VERSION = 1


def run_fingerprint(checkpoint_dir: Path, episodes: int, steps: int, spawn_steps: int) -> str:
    """What a run's rollout and summary rows come from: its model.zip and the settings (`kept_rows.fingerprint`)."""
    return fingerprint([Path(checkpoint_dir) / "model.zip"], {"episodes": episodes, "steps": steps,
                                                              "spawn_steps": spawn_steps, "version": ROWS_VERSION})


def _airborne_auroc(scores: pd.Series, airborne: pd.Series) -> float:
    """AUROC (`scoring.metrics.auroc`) of ``scores`` for the steps in the air (the positive class) against those on
    the floor; NaN where one side is empty."""
    return auroc(scores[~airborne], scores[airborne]) if 0 < airborne.sum() < len(airborne) else np.nan


def spawn_summary(rollouts: pd.DataFrame, spawn_steps: int = 10) -> pd.DataFrame:
    """Per run: uncertainty in the first ``spawn_steps`` steps over that later, and how well it flags the air.

    ``<measure>_spawn_ratio`` above 1: higher at spawn; ``<measure>_airborne_auroc`` above 0.5: higher in
    the air than on the floor (over every step played; NaN where the robot never left, or never touched,
    the floor). ``airborne_share_spawn`` / ``_later``: the share of steps without floor contact.
    """
    rows = []
    for (env_id, method, seed), run in rollouts.groupby(["env", "method", "seed"], sort=False):
        spawn = run.step < spawn_steps
        row = {"env": env_id, "method": method, "seed": seed, "spawn_steps": spawn_steps,
               "airborne_share_spawn": run.airborne[spawn].mean(), "airborne_share_later": run.airborne[~spawn].mean()}
        for measure in MEASURES:
            row[f"{measure}_spawn_ratio"] = run[measure][spawn].mean() / run[measure][~spawn].mean()
            row[f"{measure}_airborne_auroc"] = _airborne_auroc(run[measure], run.airborne)
        rows.append(row)
    return pd.DataFrame(rows)


def relative_uncertainty(rollouts: pd.DataFrame, measure: str, spawn_steps: int = 10) -> pd.Series:
    """``measure`` over its run's mean after the spawn window: 1 is the run's usual level, so methods compare."""
    run = ["env", "method", "seed"]
    later = rollouts[measure].where(rollouts.step >= spawn_steps)
    return rollouts[measure] / later.groupby([rollouts[c] for c in run]).transform("mean")


def spawn_table(summary: pd.DataFrame) -> pd.DataFrame:
    """Per (env, method): the summary's columns as the mean over seeds, with the number of seeds."""
    values = [c for c in summary.columns if c.endswith(("_ratio", "_auroc")) or c.startswith("airborne_share")]
    table = summary.groupby(["env", "method"], sort=False)[values].mean()
    cells = summary.groupby(["env", "method"], sort=False)
    return table.assign(seeds=cells.size(), spawn_steps=cells.spawn_steps.first()).reset_index()


def spawn_reading(table: pd.DataFrame) -> list[str]:
    """One line per env: does value uncertainty rise at spawn and in the air, for how many methods?"""
    lines = []
    for env_id, rows in table.groupby("env", sort=False):
        raised = rows[rows.value_std_spawn_ratio > 1].method.tolist()
        flagged = rows[rows.value_std_airborne_auroc > 0.5].method.tolist()
        never_touches = (rows.airborne_share_spawn == 1).all() and (rows.airborne_share_later == 1).all()
        air = ("no floor contact at all" if never_touches else
               f"in the air on {rows.airborne_share_spawn.mean():.0%} of the first {int(rows.spawn_steps.iloc[0])} "
               f"steps, {rows.airborne_share_later.mean():.0%} later")
        ratios = ", ".join(f"{r.method} {r.value_std_spawn_ratio:.2f}" for r in rows.itertuples())
        aurocs = ", ".join(f"{r.method} {r.value_std_airborne_auroc:.2f}" for r in rows.itertuples()
                           if pd.notna(r.value_std_airborne_auroc))
        line = (f"**{env_id}** ({air}): value_std at spawn over later: {ratios} (above 1 for {len(raised)} of "
                f"{len(rows)} methods)")
        line += (f"; AUROC of value_std for steps in the air against steps on the floor: {aurocs} (above 0.5 for "
                 f"{len(flagged)} of {len(rows)})." if aurocs else "; no AUROC: the robot was always, or never, "
                 "on the floor.")
        lines.append(line)
    control = table[(table.airborne_share_spawn == 1) & (table.airborne_share_later == 1)]
    if len(control) and (control.value_std_spawn_ratio > 1).any():
        lines.append(f"Where the robot never touches the floor ({', '.join(pd.unique(control.env))}), value_std is "
                     f"higher at spawn too, for {int((control.value_std_spawn_ratio > 1).sum())} of {len(control)} "
                     "(env, method) cells: a rise right after reset does not by itself show detachment (the first states, "
                     "at rest, are rare in training); the AUROC over every step in the air is the sharper test.")
    return lines
