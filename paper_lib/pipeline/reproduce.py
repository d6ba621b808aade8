"""The README's commands: rebuild every table and figure, re-collect, or retrain (the last two are long).

    python -m paper_lib.pipeline.reproduce               # make reproduce: never trains, never collects
    python -m paper_lib.pipeline.reproduce --recollect   # make recollect: ID/OOD states and reward episodes again, then the above
    python -m paper_lib.pipeline.reproduce --retrain     # make retrain: plain `dvc repro`, trains missing or changed runs (hours)

The default command only reads committed files and never steps an env: each run's `score` stage where `dvc status`
finds it stale (scoring reads a committed dataset), each member run's `common_score` (the baseline's states of its
seed) and each MuJoCo run's `sequence_score` (the sequence detectors on its dataset) likewise, and every table and
figure stage, forced, for the runs and recordings that exist. Whatever simulates (collection, evaluation episodes, the recordings notebooks 00 and 07 draw,
the `guard`, `spawn`, `value_level` and `ensembles_scores` experiments) belongs to `--recollect`: MuJoCo's last
float bits differ across CPUs and chaotic episodes amplify them, so a simulated number would move from machine to
machine. Runs of the profile that lack a checkpoint, dataset or evaluation are listed (printed and in
results/<profile>/runs.md), never made. It calls DVC with `--single-item`, so no upstream stage can run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from paper_lib.pipeline.config import RunConfig, load_run_config
from paper_lib.pipeline.layout import (ENSEMBLE_PARTS, QUICKSTART_RUN, RUN_FOLDERS, SEQUENCE_STAGE, common_runs,
                                       pedm_runs, sequence_runs)
from paper_lib.pipeline.run_list import write_run_list
from paper_lib.agents.envs import MUJOCO_ENVS
from paper_lib.pipeline.status import (
    available_runs,
    has,
    missing_lines,
    stage_suffix,
    stale_lines,
    stale_stages,
    status_table,
    summary,
    write_status,
)

#: Table and figure stages in dependency order (paper_vs_us reads what rewards and ood write).
TABLE_STAGES = ("rewards", "ood", "uncertainty_over_time", "training_and_perturbations", "pedm_protocol",
                "paper_vs_us", "example_states", "quickstart", "study", "scaling", "ensembles")
#: Experiments that play episodes with committed checkpoints: `make recollect` runs them where DVC finds them stale.
EXPERIMENT_STAGES = ("guard", "spawn", "value_level", "ensembles_scores")
#: What notebooks 07 and 00 draw from simulation, played once by `make recollect`.
RECORDING_STAGES = ("record_example_states", "record_quickstart")


def _has_files(folder: Path) -> bool:
    return folder.is_dir() and any(path.is_file() for path in folder.rglob("*"))


def _ensembles_trained(cfg: RunConfig) -> bool:
    """Whether either ensembles part has a trained run: each is scored and tabled without waiting for the other."""
    return any(_has_files(cfg.layout.part(part).folder("checkpoint")) for part in ENSEMBLE_PARTS)


def make_ensemble_folders(cfg: RunConfig) -> None:
    """Create the ensembles stages' declared folders (git keeps no empty folder).

    DVC refuses a stage whose dependency is missing, so with only `own` runs trained the absent `independent`
    folders would block both stages; an empty folder hashes the same on every clone.
    """
    for part in ENSEMBLE_PARTS:
        for artifact in RUN_FOLDERS:
            cfg.layout.part(part).folder(artifact).mkdir(parents=True, exist_ok=True)


def _env() -> dict[str, str]:
    """The environment for DVC: this interpreter's bin/ first, so stage commands find its python, papermill, dvc."""
    bin_dir = str(Path(sys.executable).parent)
    return {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""), "DVC_NO_ANALYTICS": "1"}


def _dvc_binary() -> str:
    local = Path(sys.executable).parent / "dvc"
    return str(local) if local.exists() else "dvc"


def _write_status(cfg: RunConfig) -> None:
    """runs.md, with the stages `dvc status` finds stale (checkpoints trained with older settings, ...)."""
    stale = stale_stages(_dvc_binary(), _env())
    path = write_status(cfg, stale)
    for line in stale_lines(status_table(cfg, stale)) if stale is not None else []:
        print(f"  note: {line}")
    print(f"run status: {path}")


def _dvc(args: list[str]) -> None:
    command = [_dvc_binary(), *args]
    print("+ dvc " + " ".join(args if len(args) < 12 else [*args[:11], f"... ({len(args) - 11} more)"]), flush=True)
    done = subprocess.run(command, env=_env(), check=False)
    if done.returncode != 0:
        raise SystemExit(f"error: `dvc {args[0]}` failed (exit status {done.returncode}); its output is above")


def table_stages(cfg: RunConfig) -> tuple[list[str], list[str]]:
    """(stages to run, lines saying why the others cannot run yet) for the runs that exist."""
    scored = available_runs(cfg, "scores")
    ready = {
        "rewards": bool(available_runs(cfg, "evaluation")),
        "ood": bool(scored),
        "uncertainty_over_time": any(run[1] != "baseline" for run in scored),
        "training_and_perturbations": bool(available_runs(cfg, "checkpoint")),
        "example_states": cfg.layout.recording("example_states").is_file(),
        "quickstart": cfg.layout.recording("quickstart").is_file(),
    }
    ready["paper_vs_us"] = ready["rewards"] and ready["ood"]
    layout = cfg.layout
    ready["study"] = layout.studies_db.is_file()
    ready["scaling"] = layout.scaling.is_dir()
    ready["pedm_protocol"] = any((layout.pedm_dir(*run) / "metrics.csv").is_file() for run in pedm_runs(cfg.runs()))
    ready["ensembles"] = layout.folder("scores").is_dir() and any(_has_files(layout.part(part).folder("scores"))
                                                                   for part in ENSEMBLE_PARTS)
    why = {"rewards": "no run has evaluation episodes", "ood": "no run has scores (no run has a dataset)",
           "uncertainty_over_time": "no member-method run has scores",
           "training_and_perturbations": "no run has a checkpoint", "paper_vs_us": "it needs both rewards and ood",
           "example_states": "its frames are not recorded yet (`make recollect`)",
           "quickstart": "its episode is not recorded yet (`make recollect`; its agent is "
                         f"{QUICKSTART_RUN[0]} {QUICKSTART_RUN[1]} seed {QUICKSTART_RUN[2]})",
           "pedm_protocol": "no MuJoCo run has played PEDM's protocol yet (`python -m paper_lib.pipeline.run_list "
                            "--pedm ENV METHOD SEED`, then `dvc repro -s pedm@ENV-METHOD-SEED`)",
           "study": "no study database yet (`dvc repro study_sweep` or `python -m paper_lib.study.worker --all`)",
           "scaling": "no scaling runs yet (`python -m paper_lib.study.scaling`)",
           "ensembles": "it needs scored independent ensembles or own runs, and scored shared runs "
                        "(`python -m paper_lib.experiments.ensembles queue`)"}
    return [s for s in TABLE_STAGES if ready[s]], [f"{s}: skipped, {why[s]}" for s in TABLE_STAGES if not ready[s]]


def experiment_stages(cfg: RunConfig) -> tuple[list[str], list[str]]:
    """(experiment stages whose inputs exist, lines saying why the others cannot run yet)."""
    mujoco_members = [run for run in available_runs(cfg, "checkpoint")
                      if run[0] in MUJOCO_ENVS and run[1] != "baseline"]
    ready = {"guard": bool(available_runs(cfg, "checkpoint")),
             "spawn": bool(mujoco_members),
             "value_level": bool(available_runs(cfg, "checkpoint", "dataset")),
             "ensembles_scores": _ensembles_trained(cfg)}
    why = {"guard": "no run has a checkpoint", "spawn": "no MuJoCo member-method run has a checkpoint",
           "value_level": "no run has a checkpoint and a dataset",
           "ensembles_scores": "no independent members or own runs trained yet (`python -m paper_lib.experiments.ensembles queue`)"}
    return [s for s in EXPERIMENT_STAGES if ready[s]], [f"{s}: skipped, {why[s]}" for s in EXPERIMENT_STAGES
                                                        if not ready[s]]


def per_run_targets(runs: list, stale: set[str] | None) -> list[list[str]]:
    """The per-run scoring stages to hand `dvc repro`, in order: `score`, then `common_score` (each member run on its
    baseline's states, issue 66), then `sequence_score` (the sequence detectors on the MuJoCo datasets, issue 69).

    Given `stale` (one `dvc status`), only the stages it names: `dvc repro` loads dvc.yaml once per stage named on its
    command line (about 7.5 s each here, about 39 min for the ~309 stages of the main matrix), while `dvc status`
    checks them all in one load (2-3 min). With `stale` None (a rescore, or `dvc status` failed) every stage, as DVC
    would pick.
    """
    groups = [[f"score@{stage_suffix(*run)}" for run in runs],
              [f"common_score@{stage_suffix(*run)}" for run in common_runs(runs)],
              [f"{SEQUENCE_STAGE}@{stage_suffix(*run)}" for run in sequence_runs(runs)]]
    if stale is not None:
        groups = [[name for name in group if name in stale] for group in groups]
    return [group for group in groups if group]


def reproduce(cfg: RunConfig, rescore: bool = False) -> None:
    """Score the runs with a dataset where stale (all of them with `rescore`), then every table and figure, forced;
    nothing here steps an env."""
    print(summary(cfg))
    path, changed = write_run_list(cfg)  # the per-run stages of dvc.yaml: the runs with a checkpoint
    if changed:
        print(f"  note: {path} now lists the {len(available_runs(cfg, 'checkpoint'))} runs with a checkpoint")
    for line in missing_lines(cfg, artifacts=("checkpoint", "dataset", "evaluation")):  # scores are made below
        print(f"  missing (not made here): {line}")
    runs = available_runs(cfg, "checkpoint", "dataset")
    stale = None if rescore else stale_stages(_dvc_binary(), _env())
    for targets in per_run_targets(runs, stale):
        _dvc(["repro", "--single-item", *(["--force"] if rescore else []), *targets])
    if _ensembles_trained(cfg):
        make_ensemble_folders(cfg)  # the ensembles notebook's declared inputs
    stages, skipped = table_stages(cfg)
    for line in skipped:
        print(f"  {line}")
    _dvc(["repro", "--single-item", "--force", *stages])
    _write_status(cfg)


def _per_run_files(cfg: RunConfig, runs: list) -> list[Path]:
    """The files a recollection rewrites and `verify` knows how to judge: evaluation episodes and scores."""
    from paper_lib.pipeline.run_results import evaluation_path, score_files, scores_dir

    files = [evaluation_path(cfg, *run) for run in runs]
    files += [scores_dir(cfg, *run) / name for run in runs for name in score_files(run[0])]
    return [path for path in files if path.is_file()]


def report_recollection(before: dict[Path, Path]) -> int:
    """Each rewritten file against its copy from before, with `verify`'s tolerances; the number outside them."""
    from paper_lib.pipeline.verify import PASSING, compare_files

    outside = []
    for path, old in before.items():
        found = compare_files(old, path)
        if found.result not in PASSING:
            outside.append(f"  {path}: {found.result} (largest difference {found.max_abs_diff:.3g} in "
                           f"{found.column or '-'}{'; ' + found.note if found.note else ''})")
    print(f"recollection: {len(before) - len(outside)} of {len(before)} evaluation and score files within "
          "`make verify`'s tolerances of the files they replaced" + (":" if outside else "."))
    print("\n".join(outside))
    return len(outside)


def recollect(cfg: RunConfig) -> None:
    """Everything that simulates, again: ID/OOD states and evaluation episodes of every run with a checkpoint, the
    recordings, the experiments where stale; then `reproduce`; then a report of every evaluation and score file
    against the one it replaced, with `make verify`'s tolerances (git diff shows the rest)."""
    runs = available_runs(cfg, "checkpoint")
    with tempfile.TemporaryDirectory(prefix="recollect-") as tmp:
        before = {}
        for i, path in enumerate(_per_run_files(cfg, runs)):
            before[path] = Path(tmp) / f"{i}{path.suffix}"
            shutil.copyfile(path, before[path])
        _recollect(cfg, runs)
        report_recollection(before)


def _recollect(cfg: RunConfig, runs: list) -> None:
    recordings = [stage for stage in RECORDING_STAGES
                  if stage != "record_quickstart" or has(cfg, QUICKSTART_RUN, "checkpoint")]
    _dvc(["repro", "--single-item", "--force", *recordings,
          *[f"{stage}@{stage_suffix(*run)}" for run in runs for stage in ("collect", "evaluate")]])
    experiments, skipped = experiment_stages(cfg)
    for line in skipped:
        print(f"  {line}")
    if "ensembles_scores" in experiments:
        make_ensemble_folders(cfg)
    if experiments:
        _dvc(["repro", "--single-item", *experiments])
    reproduce(cfg)


def retrain(cfg: RunConfig) -> None:
    """Plain `dvc repro`: trains every missing or changed run of the profile, then everything downstream."""
    print(f"{summary(cfg)}\nretraining: `dvc repro` trains every run whose checkpoint is missing or whose "
          "hyperparameters changed; at the paper's budget that is hours per run")
    write_run_list(cfg, cfg.runs())  # every run of the profile gets its stages while it trains
    try:
        _dvc(["repro"])
    finally:
        write_run_list(cfg)  # then only the runs that landed keep them
    _write_status(cfg)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--recollect", action="store_true",
                      help="everything that simulates again: states, evaluation episodes, recordings, experiments (long)")
    mode.add_argument("--retrain", action="store_true", help="train missing or changed runs (hours), then everything")
    mode.add_argument("--rescore", action="store_true", help="score every run again even where DVC finds it up to date")
    args = parser.parse_args(argv)
    try:
        cfg = load_run_config()  # dvc.yaml reads params.yaml too
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")
    if args.retrain:
        retrain(cfg)
    elif args.recollect:
        recollect(cfg)
    else:
        reproduce(cfg, rescore=args.rescore)


if __name__ == "__main__":
    main()
