"""How far each long run has come, from its resume points: what a session's note on issue 38 reports.

    python scripts/training_progress.py [TREE ...]        default: this repository

One row per resume point under TREE/results: the live ones a training tree writes (`.<run>.resume/state.pkl`,
paper_lib.agents.training) and the copies committed for the next machine (`results/resume_points/<run>/`,
scripts/resume_points.sh). Steps against the run's budget, wall time over all its segments, the training reward
of its last logged rollout (episodes ended in it, as SB3's ep_info_buffer counts them: the last 100), and the
hours left at the speed of its latest segment, which is the machine and the load it runs under now. A run is
`finished` when its checkpoint folder in the same tree holds a config.json trained to the resume point's step (its
budget is then that file's), `at budget` when it has reached its budget but that checkpoint is not there (a final
resume point, which lands in seconds), else `in progress`. A tree with live resume points is a training tree: its
committed copies are those of the commit it was made from, so only its live rows are listed. Without a finished
checkpoint the budget is the recipe's, which a `--timesteps` on the training command overrides without the resume
point knowing (scripts/issue38.q names those).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path
from typing import Any

import pandas as pd

from paper_lib.agents.training import finished_budget

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = Path("resume_points")


def resume_points(tree: Path) -> list[tuple[str, str, Path]]:
    """(run, where, state.pkl) of every resume point under tree/results; a run is named by its checkpoint path
    under results/, `where` is "live" (a training tree's) or "committed" (a copy for the next machine)."""
    results = tree / "results"
    found = []
    for state in sorted(results.rglob("state.pkl")):
        folder = state.parent.relative_to(results)
        if folder.parts[0] == COMMITTED.name:
            found.append(("/".join(folder.parts[1:]), "committed", state))
        elif folder.name.startswith(".") and folder.name.endswith(".resume"):
            found.append(("/".join((*folder.parts[:-1], folder.name[1:-len(".resume")])), "live", state))
    return found


def finished_at(checkpoint: Path, steps: int) -> int | None:
    """The budget of a run whose checkpoint was written at `steps`, or None if it has not finished there."""
    budget = finished_budget(checkpoint)  # the library's reading of a finished run's config.json
    if budget is None:
        return None
    return budget if json.loads((checkpoint / "config.json").read_text()).get("trained_timesteps") == steps else None


def progress_row(run: str, where: str, state_file: Path, results: Path) -> dict[str, Any]:
    """One run's steps, budget, wall hours, last training reward and hours left at its latest speed."""
    with open(state_file, "rb") as f:
        state = pickle.load(f)
    steps = int(state["num_timesteps"])
    budget = finished_at(results / run, steps)
    if budget is not None:
        status = "finished"
    else:
        budget = (state.get("config") or {}).get("total_timesteps")
        status = "at budget" if budget is not None and steps >= budget else "in progress"
    last = state["rows"][-1] if state.get("rows") else {}
    segment = (state.get("segments") or [{}])[-1]
    seconds = segment.get("wall_seconds")
    rate = (segment["to_step"] - segment["from_step"]) / seconds * 3600 if seconds else None
    left = max(budget - steps, 0) / rate if budget and rate else None
    return {"run": run, "where": where, "status": status, "steps": steps,
            "budget": budget, "wall_h": round(state.get("wall_seconds", 0.0) / 3600, 2),
            "reward": round(last["reward"], 1) if "reward" in last else None,
            "steps_per_h": round(rate) if rate else None,
            "hours_left": round(left, 2) if left is not None else None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trees", nargs="*", type=Path, default=[ROOT], help="repositories or training worktrees")
    args = parser.parse_args(argv)
    for tree in args.trees:
        if not (tree / "results").is_dir():
            parser.exit(2, f"error: {tree} has no results/ folder: give the repository or a training worktree\n")
        found = resume_points(tree)
        live = [point for point in found if point[1] == "live"]
        # A training worktree's own committed copies are those of the commit it was made from, long behind its
        # live runs: listing them beside the live rows reads as runs gone backwards. The repository's are current.
        shown = live or found
        rows = [progress_row(run, where, state, tree / "results") for run, where, state in shown]
        skipped = len(found) - len(shown)
        print(f"{tree}: {len(rows)} resume point(s)"
              + (f" ({skipped} committed copies of this training tree's commit not listed: give the repository"
                 " for the current ones)" if skipped else ""))
        if rows:
            print(pd.DataFrame(rows).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
