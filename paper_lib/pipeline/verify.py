"""Do the committed per-run results reproduce on this machine? Recompute them aside and compare, file by file.

Same seed, same machine: same numbers. `python -m paper_lib.pipeline.verify` runs the `score` stage (and with
`--stages evaluate score` the `evaluate` stage) of committed runs again, from their committed checkpoints
and datasets and with the current code and params.yaml, into a scratch folder, and compares every file
it writes with the committed one. Nothing under results/ is written. A file is `identical` (same bytes),
`same values` (the same table written otherwise), `numbers differ` (same table, some numbers not equal: the largest absolute difference and its column are
reported; at float32 precision, ~1e-7, this is what another CPU or BLAS thread count does), or `differs`
(another shape, columns or text).

Differences are judged against tolerances fixed here, before any number is read, so a report says whether a
difference matters: scores are `within tolerance` when no number moved by more than its column's tolerance: a rank
metric by FLIPPED_STATES swapped states' worth (1/n_ood per state for ROC tpr, 1/n_id for fpr, 1/(n_id + n_ood) for
the summaries, the run's counts read from its committed metrics.csv), a continuous score by RELATIVE_TOLERANCE of
its column's typical size; FLOAT_TOLERANCE where the counts are unknown. So an untouched clone verifies on any CPU
while a tampered AUROC (0.01 on 6000 states is 12 times the tolerance) still fails; reward
episodes are chaotic (MuJoCo's last bits, amplified), so an evaluation file is judged as a sample, not episode by
episode: `same distribution` when, for every (inference, deterministic, member) group, Welch's t-test does not tell
the recomputed rewards from the committed ones at level EPISODE_ALPHA.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from pandas.api.types import is_integer_dtype

from paper_lib.common.provenance import machine
from paper_lib.pipeline.config import RunConfig, load_run_config
from paper_lib.pipeline.run_results import (PROVENANCE_FILE, evaluate_run, evaluation_path, score_files,
                                             score_run_files, scores_dir)
from paper_lib.pipeline.status import Run, available_runs

STAGES = ("evaluate", "score")
#: What each stage needs committed to be recomputed and compared.
#: Results that count as reproduced.
PASSING = ("identical", "same values", "within tolerance", "same distribution")
#: The largest absolute difference that counts as float32 noise where nothing better is known (no state counts).
FLOAT_TOLERANCE = 1e-5
#: Metrics made from ranks (ROC points, AUROC, AUPR, FPR@95, detection error, their bootstrap replicates) move in
#: steps: another CPU's last float bits swap a few nearly tied states, and each such state moves a ROC point by 1/n
#: of its side and a summary by about 1/n or (AUROC) far less. This many states may swap: 2 were seen (ROC tpr 4e-4
#: at 5000 OOD states, AVX-512 against the committing CPU, 2026-12-02); a changed score moves hundreds.
FLIPPED_STATES = 5
#: Continuous columns (uncertainty values and their ratios) may move by this share of the column's typical size
#: (median |x|): float32 keeps about 7 digits, and a std over k nearly equal member values loses up to 4 of them to
#: cancellation (seen: 6e-4 of its median, Swimmer value std, the same host). 2e-3 stays below the third significant
#: digit that tables and figures show.
RELATIVE_TOLERANCE = 2e-3
#: Columns judged as rank metrics; "array" is replicates.npy (AUROC replicates).
RANK_COLUMNS = frozenset({"auroc", "auroc_ci_low", "auroc_ci_high", "aupr_in", "aupr_out", "fpr_at_95_tpr",
                          "detection_error", "auroc_scoring_std", "auroc_scoring_min", "auroc_scoring_max", "tpr",
                          "fpr", "array"})
#: Welch's test level below which recomputed reward episodes count as another distribution than the committed.
EPISODE_ALPHA = 0.01
#: The columns that name an evaluation file's episode groups (paper_lib/pipeline/run_results.py writes them).
EPISODE_GROUPS = ("inference", "deterministic", "member")
NEEDS = {"evaluate": ("checkpoint", "evaluation"), "score": ("checkpoint", "dataset", "scores")}


@dataclass(frozen=True)
class Comparison:
    """How a recomputed file compares with the committed one."""

    result: str  # "identical", "same values", "within tolerance", "same distribution", "numbers differ", "differs",
    #              "missing"
    max_abs_diff: float = 0.0
    column: str = ""  # where the largest difference is (CSV column, or "array")
    note: str = ""
    tolerance: float | None = None  # that column's tolerance (`column_tolerance`); None: not judged yet


def column_tolerance(column: str, committed: np.ndarray, states: tuple[int, int] | None) -> float:
    """The largest difference of `column` that counts as float noise (see the module docstring)."""
    if column in RANK_COLUMNS:
        if states is None:
            return FLOAT_TOLERANCE
        n_id, n_ood = states
        n = n_ood if column == "tpr" else n_id if column == "fpr" else n_id + n_ood
        return max(FLOAT_TOLERANCE, FLIPPED_STATES / n)
    finite = np.abs(committed[np.isfinite(committed)])
    return max(FLOAT_TOLERANCE, RELATIVE_TOLERANCE * float(np.median(finite))) if finite.size else FLOAT_TOLERANCE


def compare_files(committed: Path, fresh: Path, states: tuple[int, int] | None = None) -> Comparison:
    """Byte equality first; else, for CSV and .npy, the largest numeric difference (NaN equals NaN), judged by
    `column_tolerance` (`states`: the run's ID and OOD state counts, for rank metrics)."""
    if not committed.is_file() or not fresh.is_file():
        return Comparison("missing", note=f"{committed if not committed.is_file() else fresh} does not exist")
    if committed.read_bytes() == fresh.read_bytes():
        return Comparison("identical")
    if committed.suffix == ".npy":
        a, b = np.load(committed), np.load(fresh)
        if a.shape != b.shape:
            return Comparison("differs", note=f"shape {a.shape} committed, {b.shape} recomputed")
        return _within_tolerance(_numbers(a.astype(np.float64), b.astype(np.float64), "array", states), states)
    if committed.suffix == ".csv":
        a, b = pd.read_csv(committed), pd.read_csv(fresh)
        if "reward" in a.columns and set(EPISODE_GROUPS) <= set(a.columns):
            return _compare_episodes(a, b)
        return _within_tolerance(_compare_tables(a, b, states), states)
    return Comparison("differs", note="not a CSV or .npy file, and its bytes differ")


def _within_tolerance(found: Comparison, states: tuple[int, int] | None = None) -> Comparison:
    """`found` (its worst column by difference / tolerance) as within tolerance or not."""
    if found.result != "numbers differ":
        return found
    tolerance = FLOAT_TOLERANCE if found.tolerance is None else found.tolerance
    if found.max_abs_diff <= tolerance:
        return dataclasses.replace(found, result="within tolerance", note=f"<= {tolerance:.3g}")
    return dataclasses.replace(found, note=f"> {tolerance:.3g}")


def _compare_episodes(a: pd.DataFrame, b: pd.DataFrame) -> Comparison:
    """Reward episodes: every column but reward and length the same, then each group's rewards as a sample."""
    from scipy.stats import ttest_ind

    found = _compare_tables(a, b)
    if found.result != "numbers differ" and found.result != "differs":
        return found
    if list(a.columns) != list(b.columns) or a.shape != b.shape:
        return found
    labels = [c for c in a.columns if c not in ("reward", "length")]
    same = _compare_tables(a[labels], b[labels])
    if same.result not in ("same values", "identical"):
        return same
    groups = a[list(EPISODE_GROUPS)].astype(str).groupby(list(EPISODE_GROUPS), sort=False, dropna=False).groups
    smallest = 1.0
    for rows in groups.values():
        x, y = a.loc[rows, "reward"].to_numpy(float), b.loc[rows, "reward"].to_numpy(float)
        if len(x) < 2 or (np.ptp(x) == 0 and np.ptp(y) == 0):
            p = 1.0 if np.allclose(x, y) else 0.0
        else:
            p = float(ttest_ind(x, y, equal_var=False).pvalue)
        smallest = min(smallest, p)
    result = "same distribution" if smallest >= EPISODE_ALPHA else "numbers differ"
    return Comparison(result, found.max_abs_diff, found.column,
                      note=f"episodes differ one by one; smallest Welch p over its groups {smallest:.3g} "
                           f"({'>=' if smallest >= EPISODE_ALPHA else '<'} {EPISODE_ALPHA})")


def _compare_tables(a: pd.DataFrame, b: pd.DataFrame, states: tuple[int, int] | None = None) -> Comparison:
    """Same columns and text; the numeric column whose difference is largest against its own tolerance."""
    if list(a.columns) != list(b.columns) or a.shape != b.shape:
        return Comparison("differs", note=f"columns or shape differ: {a.shape} committed, {b.shape} recomputed")
    largest, worst = Comparison("same values"), -1.0
    for column in a.columns:
        x, y = a[column], b[column]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            found = _numbers(x.to_numpy(np.float64), y.to_numpy(np.float64), str(column), states)
            if found.result == "differs":
                return found
            if found.result == "numbers differ" and is_integer_dtype(x) and is_integer_dtype(y):
                found = dataclasses.replace(found, tolerance=0.0)  # counts, steps, seeds: any change is real
            excess = found.max_abs_diff / found.tolerance if found.tolerance else np.inf
            if found.result == "numbers differ" and excess > worst:
                largest, worst = found, excess
        elif not x.astype(str).equals(y.astype(str)):
            row = int(np.flatnonzero(x.astype(str).to_numpy() != y.astype(str).to_numpy())[0])
            return Comparison("differs", column=str(column), note=f"row {row}: {x.iloc[row]!r} committed, "
                                                                   f"{y.iloc[row]!r} recomputed")
    return largest


def _numbers(a: np.ndarray, b: np.ndarray, column: str, states: tuple[int, int] | None = None) -> Comparison:
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if not np.array_equal(nan_a, nan_b):
        return Comparison("differs", column=column, note="NaN in one file where the other has a number")
    diff = np.abs(a[~nan_a] - b[~nan_b])
    largest = float(diff.max()) if diff.size else 0.0
    if largest == 0:
        return Comparison("same values")
    return Comparison("numbers differ", largest, column, tolerance=column_tolerance(column, a, states))


def _scratch_config(cfg: RunConfig, scratch: Path, run: Run) -> RunConfig:
    """A config rooted in `scratch` whose checkpoint and dataset of `run` are links to the committed ones."""
    aside = dataclasses.replace(cfg, root=scratch)
    for committed, linked in ((cfg.checkpoint_dir(*run), aside.checkpoint_dir(*run)),
                              (cfg.dataset_path(*run), aside.dataset_path(*run))):
        if committed.exists() and not linked.exists():
            linked.parent.mkdir(parents=True, exist_ok=True)
            linked.symlink_to(committed.resolve(), target_is_directory=committed.is_dir())
    return aside


def _state_counts(metrics: Path) -> tuple[int, int] | None:
    """(ID, OOD) states of a run's committed scores, the fewest over its rows; None where they are not recorded."""
    try:
        table = pd.read_csv(metrics, usecols=["n_id", "n_ood"])
    except (OSError, ValueError):
        return None
    return (int(table["n_id"].min()), int(table["n_ood"].min())) if len(table) else None


def verify_run(cfg: RunConfig, run: Run, stages: tuple[str, ...] = ("score",)) -> pd.DataFrame:
    """Recompute `stages` of one committed run aside and compare each file: one row per file."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="verify-") as tmp:
        aside = _scratch_config(cfg, Path(tmp), run)
        for stage in stages:
            started = time.perf_counter()
            if stage == "evaluate":
                evaluate_run(aside, *run)
                pairs = [(evaluation_path(cfg, *run), evaluation_path(aside, *run))]
            else:
                score_run_files(aside, *run)
                names = (*score_files(run[0]), PROVENANCE_FILE)  # what the scores were made from, too
                pairs = [(scores_dir(cfg, *run) / name, scores_dir(aside, *run) / name) for name in names]
            seconds = time.perf_counter() - started
            states = _state_counts(scores_dir(cfg, *run) / "metrics.csv") if stage == "score" else None
            for committed, fresh in pairs:
                found = compare_files(committed, fresh, states)
                rows.append({"env": run[0], "method": run[1], "seed": run[2], "stage": stage, "file": committed.name,
                             **dataclasses.asdict(found), "seconds": round(seconds, 1)})
    return pd.DataFrame(rows)


def runs_to_verify(cfg: RunConfig, stages: tuple[str, ...], requested: list[Run] | None = None,
                   every: bool = False) -> list[Run]:
    """The requested runs (each must have what its stages compare), every such run, or the first of each env."""
    needs = tuple(dict.fromkeys(n for s in stages for n in NEEDS[s]))
    ready = available_runs(cfg, *needs)
    if requested:
        missing = [r for r in requested if r not in ready]
        if missing:
            env, method, seed = missing[0]
            raise ValueError(f"{env} {method} seed {seed} has no committed {' + '.join(needs)} in profile "
                             f"{cfg.profile!r} to compare with; runs that have them: "
                             f"{', '.join(f'{e} {m} {s}' for e, m, s in ready[:8]) or 'none'}"
                             f"{' ...' if len(ready) > 8 else ''}")
        return list(requested)
    if every:
        return ready
    first: dict[str, Run] = {}
    for run in ready:
        first.setdefault(run[0], run)
    return list(first.values())


def _seed(text: str) -> int:
    if not text.isdigit():
        raise ValueError(f"--run takes ENV METHOD SEED with an integer seed, e.g. --run HalfCheetah-v5 masksembles 0; "
                         f"got seed {text!r}")
    return int(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", nargs=3, action="append", metavar=("ENV", "METHOD", "SEED"),
                        help="a committed run to verify (repeatable); default: the first complete run of each env")
    parser.add_argument("--all", action="store_true", help="every committed run (slow: minutes per run)")
    parser.add_argument("--stages", nargs="+", choices=STAGES, default=["score"],
                        help="which per-run stages to recompute (default: score; evaluate plays every episode again)")
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args(argv)
    stages = tuple(s for s in STAGES if s in args.stages)
    try:
        cfg = load_run_config(args.params)
        requested = [(env, method, _seed(seed)) for env, method, seed in args.run or []]
        runs = runs_to_verify(cfg, stages, requested, args.all)
    except ValueError as err:
        parser.exit(2, f"error: {err}\n")
    here = machine()
    print(f"recomputing on {here['cpu']} ({here['cpus']} CPUs; {here['simd'] or 'no AVX'}), {here['platform']}")
    frames = []
    for run in runs:
        frame = verify_run(cfg, run, stages)
        frames.append(frame)
        worst = frame.sort_values("max_abs_diff").iloc[-1]
        print(f"{run[0]} {run[1]} seed {run[2]}: {frame.result.isin(PASSING).sum()} of {len(frame)} files within tolerance"
              + ("" if worst.max_abs_diff == 0 else f" (largest difference {worst.max_abs_diff:.3g} in "
                 f"{worst.file}, {worst.column})"), flush=True)
    table = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    different = table[~table.result.isin(PASSING)] if len(table) else table
    print(f"\n{len(table) - len(different)} of {len(table)} files the same as the committed ones or within tolerance "
          f"({len(runs)} run(s), stages {', '.join(stages)}).")
    if len(different):
        print(different.drop(columns=["seconds"]).to_markdown(index=False))
        print(f"\nOutside the tolerances (each row's `tolerance`: rank metrics {FLIPPED_STATES} swapped states' worth "
              f"of the run's states, continuous scores {RELATIVE_TOLERANCE:g} of their column's median, counts exact; "
              f"reward episodes: Welch's p >= {EPISODE_ALPHA} per group). Another CPU's last float bits stay inside "
              "these; a number outside them means changed code, params.yaml or packages (`dvc status` lists stale "
              "stages), or an edited file. Reward episodes go their own way from the first differing bit (physics "
              "and games amplify it), so on another CPU their rewards differ by up to the episodes' spread.")
    return 1 if len(different) else 0


if __name__ == "__main__":
    sys.exit(main())
