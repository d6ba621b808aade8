"""Which runs of the active profile exist, and what each has: checkpoint, dataset, evaluation, scores.

    python -m paper_lib.pipeline.status      # prints the runs that are missing something, writes results/<profile>/runs.md
    python -m paper_lib.pipeline.status queue [--resume-root DIR] [--envs ...] [--methods ...]
                                             # the training line of every run without a checkpoint, seed-major,
                                             # for scripts/train_queue.sh (then scripts/land_run.sh lands each)

The tables and figures are built from the runs that exist (a profile may be partly trained:
3 of 8 envs, some seeds missing); this module is the one place that says which those are, so
every notebook skips the same runs and the missing ones are listed instead of trained.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from paper_lib.agents.envs import is_atari
from paper_lib.common.io import write_text_atomic
from paper_lib.pipeline.config import RunConfig, load_run_config
from paper_lib.pipeline.layout import Layout, Run, stage_suffix  # stage_suffix: re-exported
from paper_lib.pipeline.run_results import evaluation_path, score_files, scores_dir

#: What a run can have, in pipeline order, and the command that makes each.
ARTIFACTS = {
    "checkpoint": "make retrain (hours) or `dvc repro -s train@{stage}`",
    "dataset": "make recollect, or `dvc repro -s collect@{stage}`",
    "evaluation": "make recollect, or `dvc repro -s evaluate@{stage}`",
    "scores": "make reproduce, once the run has its dataset",
}


def has(cfg: RunConfig, run: Run, artifact: str) -> bool:
    """Whether `run` has `artifact` (one of ARTIFACTS) on disk."""
    if artifact == "checkpoint":
        return cfg.layout.has_checkpoint(*run)
    if artifact == "dataset":
        return cfg.dataset_path(*run).is_file()
    if artifact == "evaluation":
        return evaluation_path(cfg, *run).is_file()
    if artifact == "scores":
        return all((scores_dir(cfg, *run) / name).is_file() for name in score_files(run[0]))
    raise ValueError(f"unknown artifact {artifact!r}; use one of {list(ARTIFACTS)}")


def available_runs(cfg: RunConfig, *needs: str, methods: list[str] | None = None) -> list[Run]:
    """The profile's runs that have every artifact in `needs` (and one of `methods`, if given), in profile order."""
    return [run for run in cfg.runs() if (methods is None or run[1] in methods) and all(has(cfg, run, a) for a in needs)]


#: Per-run stages whose staleness (`dvc status`) the status table reports, and what a stale one means.
STALE_MEANING = {"train": "trained before their settings in params.yaml, the training notebook or its command last "
                          "changed (`make retrain` trains them again)",
                 "collect": "collected before the collection code or settings last changed (`make recollect`)",
                 "evaluate": "evaluated before the evaluation code or settings last changed (`make recollect`)"}


#: The artifact each per-run stage makes.
STAGE_OUTPUT = {"train": "checkpoint", "collect": "dataset", "evaluate": "evaluation"}


def stale_stages(dvc: str = "dvc", env: dict[str, str] | None = None) -> set[str] | None:
    """Names of the stages `dvc status` finds changed (e.g. 'train@HalfCheetah-v5-masksembles-0'); None if it fails."""
    import json
    import subprocess

    done = subprocess.run([dvc, "status", "--json"], capture_output=True, text=True, env=env, check=False)
    try:
        return set(json.loads(done.stdout)) if done.returncode == 0 else None
    except json.JSONDecodeError:
        return None


def status_table(cfg: RunConfig, stale: set[str] | None = None) -> pd.DataFrame:
    """One row per run of the profile: env, method, seed, yes/no per artifact and, given `stale`, its stale stages."""
    rows = []
    for e, m, s in cfg.runs():
        row = {"env": e, "method": m, "seed": s, **{a: "yes" if has(cfg, (e, m, s), a) else "no" for a in ARTIFACTS}}
        if stale is not None:
            row["stale (dvc status)"] = ", ".join(  # a stage that never ran (its output is missing) is not stale
                st for st in STALE_MEANING
                if f"{st}@{stage_suffix(e, m, s)}" in stale and row[STAGE_OUTPUT[st]] == "yes") or "-"
        rows.append(row)
    return pd.DataFrame(rows, columns=["env", "method", "seed", *ARTIFACTS] + (["stale (dvc status)"] if stale is not None else []))


def missing_lines(cfg: RunConfig, table: pd.DataFrame | None = None, artifacts: tuple[str, ...] = tuple(ARTIFACTS)
                  ) -> list[str]:
    """One line per run that lacks one of `artifacts`: what it lacks and the command that makes it."""
    table = status_table(cfg) if table is None else table
    lines = []
    for row in table.itertuples(index=False):
        lacking = [a for a in artifacts if getattr(row, a) == "no"]
        if lacking:
            how = ARTIFACTS[lacking[0]].format(stage=stage_suffix(row.env, row.method, row.seed))
            lines.append(f"{row.env} {row.method} seed {row.seed}: no {', no '.join(lacking)} ({how})")
    return lines


def began_on_gpu(config: dict) -> bool:
    """Whether part of the run trained on an accelerator (config.json's `segments`): its wall time is not a CPU run's."""
    return any(segment.get("device", "cpu") not in ("cpu", "not recorded") for segment in config.get("segments") or [])


def run_config(cfg: RunConfig, run: Run) -> dict | None:
    """The run's config.json, or None without a checkpoint."""
    path = cfg.checkpoint_dir(*run) / "config.json"
    return json.loads(path.read_text()) if path.is_file() else None


def cpu_minutes(config: dict | None) -> float | None:
    """A run's training wall time in minutes on the CPU (`wall_seconds`, all resumed pieces).

    None without a checkpoint, and for runs that trained partly on a GPU: they would make this machine look
    faster than it is.
    """
    seconds = None if config is None else config.get("wall_seconds")
    return None if seconds is None or began_on_gpu(config) else seconds / 60


def training_minutes(cfg: RunConfig, run: Run) -> float | None:
    """`cpu_minutes` of the run's config.json."""
    return cpu_minutes(run_config(cfg, run))


def training_time_line(cfg: RunConfig, table: pd.DataFrame | None = None) -> str:
    """'Training wall time of the 7 runs trained on the CPU: 5.3 h in total (one core each), 33-53 min a run' and the like."""
    table = status_table(cfg) if table is None else table
    configs = [c for row in table.itertuples(index=False)
               if (c := run_config(cfg, (row.env, row.method, row.seed))) is not None]
    minutes = [m for c in configs if (m := cpu_minutes(c)) is not None]
    on_gpu = sum(began_on_gpu(c) for c in configs)
    runs_are = f"{on_gpu} runs begun on a lent GPU are" if on_gpu > 1 else "1 run begun on a lent GPU is"
    gpu_note = f" ({runs_are} left out: see config.json's segments)" if on_gpu else ""
    if not minutes:
        return "No run trained on the CPU alone records its training wall time yet." + gpu_note
    return (f"Training wall time of the {len(minutes)} runs trained on the CPU: {sum(minutes) / 60:.1f} h in total "
            f"(one core each, the sum of each run's `wall_seconds` in its config.json), "
            f"{min(minutes):.0f}-{max(minutes):.0f} min a run{gpu_note}.")


def remaining_training_line(cfg: RunConfig, table: pd.DataFrame | None = None) -> str:
    """How many core-hours the runs without a checkpoint still need, estimated from the trained ones.

    Each missing run counts the median wall time of the trained runs of its env and method, else of its
    method in the other envs of its kind (Atari or MuJoCo: the network, not the game, sets an Atari run's
    cost), else it is left out and counted as such: a plan for the queue, not a measurement.
    """
    table = status_table(cfg) if table is None else table
    trained, missing = {}, []
    for row in table.itertuples(index=False):
        run = (row.env, row.method, row.seed)
        minutes = training_minutes(cfg, run)
        if minutes is not None:
            trained.setdefault((row.env, row.method), []).append(minutes)
        elif row.checkpoint == "no":
            missing.append(run)
    if not missing:
        return ""
    estimate, unknown = 0.0, 0
    for env_id, method, _ in missing:
        same = trained.get((env_id, method)) or [m for (e, k), ms in trained.items()
                                                 if k == method and is_atari(e) == is_atari(env_id) for m in ms]
        if same:
            estimate += float(pd.Series(same).median())
        else:
            unknown += 1
    text = (f"The {len(missing)} runs without a checkpoint need about {estimate / 60:.1f} core-hours more on the "
            f"machine that trained the others (each: the median wall time of the trained runs of its env and "
            f"method, else of its method in the other envs of its kind, Atari or MuJoCo)")
    return text + (f"; {unknown} of them have no trained run of their method and kind to estimate from."
                   if unknown else ".")


def summary(cfg: RunConfig, table: pd.DataFrame | None = None) -> str:
    """'8 of 10 runs of profile cpu are complete; 2 are missing something' and the like."""
    table = status_table(cfg) if table is None else table
    complete = int((table[list(ARTIFACTS)] == "yes").all(axis=1).sum())
    counts = ", ".join(f"{int((table[a] == 'yes').sum())} with {a}" for a in ARTIFACTS)
    return f"profile {cfg.profile!r}: {len(table)} runs, {complete} complete ({counts})"


def stale_lines(table: pd.DataFrame) -> list[str]:
    """One line per kind of stale stage: how many runs, and what it means."""
    if "stale (dvc status)" not in table:
        return []
    lines = []
    for stage, meaning in STALE_MEANING.items():
        n = int(sum(stage in kinds.split(", ") for kinds in table["stale (dvc status)"]))
        if n:
            made = int((table[STAGE_OUTPUT[stage]] == "yes").sum())
            lines.append(f"{n} of the {made} runs with a {STAGE_OUTPUT[stage]} were {meaning}; "
                         "the tables use them as they are.")
    return lines


def write_status(cfg: RunConfig, stale: set[str] | None = None) -> Path:
    """results/<profile>/runs.md: the summary, the missing and stale runs with their commands, and the full table."""
    table = status_table(cfg, stale)
    lines = missing_lines(cfg, table)
    text = [f"# Runs of {summary(cfg, table)}", "",
            ("Tables and figures are built from the runs that have what they need; nothing is trained or "
             "collected by `make reproduce`."), "", training_time_line(cfg, table), ""]
    remaining = remaining_training_line(cfg, table)
    text += [remaining, ""] if remaining else []
    text += (["Missing:", ""] + [f"- {line}" for line in lines] if lines else ["Nothing is missing."]) + [""]
    text += [f"- {line}" for line in stale_lines(table)] + ([""] if stale_lines(table) else [])
    text += [table.to_markdown(index=False), ""]
    return write_text_atomic(Layout(cfg.results).status_file, "\n".join(text))


def queue_lines(cfg: RunConfig, resume_root: str | None = None, envs: list[str] | None = None,
                methods: list[str] | None = None, python: str = ".venv/bin/python") -> list[str]:
    """The `python -m paper_lib.agents.training` line of every run lacking a checkpoint, all seed-0 runs first.

    The same command the `train` stage's notebook runs (the profile's budget and overrides), so a queue
    of these lines trains what `make retrain` would, resumably, without DVC in the loop.
    """
    from paper_lib.agents.training import hp_flags, train_command

    for name, chosen, known in (("env", envs, cfg.envs), ("method", methods, cfg.methods)):
        unknown = sorted(set(chosen or []) - set(known))
        if unknown:
            raise ValueError(f"{name}(s) {unknown} are not in profile {cfg.profile!r}; it has {known}")
    runs = [run for run in cfg.runs() if (envs is None or run[0] in envs) and (methods is None or run[1] in methods)
            and not has(cfg, run, "checkpoint")]
    lines = []
    for env_id, method, seed in sorted(runs, key=lambda run: (run[2], cfg.envs.index(run[0]), cfg.methods.index(run[1]))):
        args = [env_id, method, str(seed), str(cfg.checkpoint_dir(env_id, method, seed))]
        if cfg.budget(env_id) is not None:
            args.append(f"--timesteps {cfg.budget(env_id)}")
        lines.append(train_command(args + hp_flags(cfg.overrides or {}), resume_root, python))
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--params", default="params.yaml")
    sub = parser.add_subparsers(dest="command")
    queue = sub.add_parser("queue", help="print the training line of every run without a checkpoint")
    queue.add_argument("--resume-root", help="where resume points go (PAPER_LIB_RESUME_ROOT), e.g. /work/resume")
    queue.add_argument("--envs", nargs="+")
    queue.add_argument("--methods", nargs="+")
    args = parser.parse_args(argv)
    try:
        cfg = load_run_config(args.params)
        if args.command == "queue":
            print("\n".join(queue_lines(cfg, args.resume_root, args.envs, args.methods)))
            return
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")
    print(summary(cfg))
    for line in missing_lines(cfg):
        print(f"  missing: {line}")
    print(f"written: {write_status(cfg)}")


if __name__ == "__main__":
    main()
