"""runs.yaml: the runs of the active profile that have stages in dvc.yaml.

dvc.yaml makes the per-run `train`, `collect`, `evaluate` and `score` stages for the runs listed here, not for the
profile's whole matrix: a run not trained yet has no stage, so `dvc repro` on a fresh clone trains, collects and
evaluates nothing. The list is the runs with a committed checkpoint; `make retrain` adds the profile's missing runs
while it trains them, and the main command brings the list back in line with the checkpoints on disk.

    python -m paper_lib.pipeline.run_list                          # the committed runs of the active profile
    python -m paper_lib.pipeline.run_list --add HalfCheetah-v5 baseline 0   # ask for a run to train (`dvc repro`)
    python -m paper_lib.pipeline.run_list --all                    # every run of the profile (what `make retrain` trains)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml

from paper_lib.common.io import write_text_atomic
from paper_lib.pipeline.config import RunConfig, load_run_config
from paper_lib.pipeline.layout import Run, common_runs, pedm_runs, sequence_runs, stage_suffix  # not status: `config use` imports this module

RUN_LIST = "runs.yaml"
KEY = "committed_runs"
#: The member runs that also score the baseline's states of their seed (paper_lib/pipeline/common_states.py).
COMMON_KEY = "common_runs"
#: The MuJoCo runs, whose `pedm` stages play PEDM's protocol (paper_lib/pipeline/pedm_stage.py).
PEDM_KEY = "pedm_runs"
#: The MuJoCo runs, whose `sequence_score` stages score their dataset with the sequence detectors (sequence_stage.py).
SEQUENCE_KEY = "sequence_runs"
HEADER = """\
# The runs of the active profile that have train, collect, evaluate and score stages in dvc.yaml: those with a
# committed checkpoint, so `dvc repro` on a fresh clone trains nothing (paper_lib/pipeline/run_list.py).
# Written by the main command and `make retrain`; ask for a run to train with
#   python -m paper_lib.pipeline.run_list --add <env> <method> <seed>
# common_runs: the member runs whose seed has a baseline run; their `common_score` stages score the baseline's states.
# pedm_runs: the MuJoCo runs whose `pedm` stage (PEDM's protocol) has run, or was asked for with
#   python -m paper_lib.pipeline.run_list --pedm <env> <method> <seed>      (then `dvc repro -s pedm@<env>-<method>-<seed>`)
# sequence_runs: the MuJoCo runs; their `sequence_score` stages score the run's dataset with the sequence detectors.
"""


def _entries(key: str, runs: list[Run]) -> str:
    lines = "".join(f"  {stage_suffix(*run)}: {{env: {run[0]}, method: {run[1]}, seed: {run[2]}}}\n" for run in runs)
    return f"{key}:{' {}' if not runs else ''}\n{lines}"


def run_list_text(cfg: RunConfig, runs: list[Run], pedm: list[Run] = ()) -> str:
    """runs.yaml's bytes for `runs` (in the profile's order, so equal lists give equal bytes), and under
    COMMON_KEY the member runs among them whose seed has a baseline run (the `common_score` stages), under PEDM_KEY
    the MuJoCo runs among them whose PEDM-protocol metrics exist, plus `pedm` (the `pedm` stages: so `dvc repro`
    on the committed tree plays no protocol, as it trains and collects nothing), under SEQUENCE_KEY the MuJoCo runs
    among them (the `sequence_score` stages: they read committed datasets and simulate nothing)."""
    order = {run: i for i, run in enumerate(cfg.runs())}
    listed = sorted(set(runs), key=lambda run: order.get(run, len(order)))
    played = [run for run in pedm_runs(listed) if run in pedm or (cfg.layout.pedm_dir(*run) / "metrics.csv").is_file()]
    return (f"{HEADER}profile: {cfg.profile}\n{_entries(KEY, listed)}{_entries(COMMON_KEY, common_runs(listed))}"
            f"{_entries(PEDM_KEY, played)}{_entries(SEQUENCE_KEY, sequence_runs(listed))}")


def read_run_list(root: str | Path = ".", key: str = KEY) -> tuple[str | None, list[Run]]:
    """(profile, runs) of runs.yaml (`key`: PEDM_KEY for the runs with `pedm` stages); (None, []) where there is none
    yet."""
    path = Path(root) / RUN_LIST
    if not path.is_file():
        return None, []
    data = yaml.safe_load(path.read_text()) or {}
    runs = data.get(key) or {}
    return data.get("profile"), [(entry["env"], entry["method"], int(entry["seed"])) for entry in runs.values()]


def write_run_list(cfg: RunConfig, extra: list[Run] = (), pedm: list[Run] = ()) -> tuple[Path, bool]:
    """Write runs.yaml with the runs that have a checkpoint plus `extra` (`pedm`: MuJoCo runs to give a `pedm`
    stage before their protocol has run); (path, whether its bytes changed)."""
    path = cfg.root / RUN_LIST
    text = run_list_text(cfg, [*(run for run in cfg.runs() if cfg.layout.has_checkpoint(*run)), *extra], pedm)
    changed = not path.is_file() or path.read_text() != text
    if changed:
        write_text_atomic(path, text)
    return path, changed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--add", nargs=3, action="append", default=[], metavar=("ENV", "METHOD", "SEED"),
                        help="a run of the profile to give stages, to train it with `dvc repro` (repeatable)")
    parser.add_argument("--pedm", nargs=3, action="append", default=[], metavar=("ENV", "METHOD", "SEED"),
                        help="a committed MuJoCo run to give a `pedm` stage, to play PEDM's protocol with `dvc repro -s "
                             "pedm@ENV-METHOD-SEED` (repeatable)")
    parser.add_argument("--all", action="store_true", help="every run of the profile")
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args(argv)
    try:
        cfg = load_run_config(args.params)
        profile_runs = cfg.runs()
        asked = [(env, method, int(seed)) for env, method, seed in args.add]
        protocol = [(env, method, int(seed)) for env, method, seed in args.pedm]
        unknown = [run for run in asked + protocol if run not in profile_runs]
        if unknown:
            raise ValueError(f"{unknown} are not runs of profile {cfg.profile!r} (its envs {cfg.envs}, methods "
                             f"{cfg.methods}, seeds {cfg.seeds}); edit params.yaml's run section or pick one of those")
        not_mujoco = [run for run in protocol if not pedm_runs([run])]
        if not_mujoco:
            raise ValueError(f"{not_mujoco}: PEDM's protocol is defined for the MuJoCo envs only")
        path, _ = write_run_list(cfg, profile_runs if args.all else asked, protocol)
    except ValueError as err:
        parser.exit(2, f"error: {err}\n")
    print(f"{path}: {len(read_run_list(cfg.root)[1])} runs with stages")


if __name__ == "__main__":
    main()
