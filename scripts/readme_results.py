"""Paste the active profile's tables into README.md's "Results" section, verbatim.

README numbers must be the pipeline's: this copies results/<profile>/tables/*.md between the markers
`<!-- results:start -->` and `<!-- results:end -->`, with the run count from results/<profile>/runs.md
and a short reading computed from the same tables (nothing typed by hand). Works on a partial matrix:
cells of runs not trained yet are NaN in the tables and left out of the reading.
    python scripts/readme_results.py [PROFILE]     # default: the active profile of params.yaml
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

START, END = "<!-- results:start -->", "<!-- results:end -->"
MEMBER_MEASURES = ("value_std", "policy_std", "policy_js")
FREE_PREFIXES = ("mahalanobis", "knn")


def _range(values: pd.Series) -> str:
    values = values.dropna()
    return f"{values.min():.2f}-{values.max():.2f}" if len(values) else "n/a"


def reward_lines(tables: Path) -> list[str]:
    """Ours against the paper, per run cell that exists (deterministic actions, as the paper's Table 1)."""
    vs = pd.read_csv(tables / "paper_vs_us_rewards.csv").dropna(subset=["ours"])
    lines = []
    for env, rows in vs.groupby("env", sort=False):
        cells = [f"{r.method} ({r.inference}) {r.ours:.0f} vs {r.paper:.0f}" for r in rows.itertuples()]
        lines.append(f"- **{env}, reward ours vs the paper:** " + "; ".join(cells) + ".")
    return lines


def auroc_lines(tables: Path) -> list[str]:
    """Per env: member measures against member-free detectors on perturbed states, and the paper's cells."""
    auroc = pd.read_csv(tables / "ood_auroc_perturbed.csv")
    paper = pd.read_csv(tables / "paper_vs_us_auroc.csv")
    envs = [c for c in auroc.columns if c not in ("method", "measure")]
    lines = []
    for env in envs:
        member = auroc[auroc.measure.isin(MEMBER_MEASURES)][env]
        free = auroc[auroc.measure.str.startswith(FREE_PREFIXES)][env]
        if member.dropna().empty and free.dropna().empty:
            continue
        ours = paper[(paper.env == env)].dropna(subset=["ours"])
        cells = "; ".join(f"{r.method} {r.measure} {r.ours:.2f} vs {r.paper:.2f}" for r in ours.itertuples())
        lines.append(f"- **{env}, perturbed-state AUROC:** member measures {_range(member)}, member-free "
                     f"detectors {_range(free)}" + (f"; ours vs the paper: {cells}" if cells else "") + ".")
    return lines


def reading(tables: Path) -> str:
    lines = ["What these numbers say (computed from the tables above by `scripts/readme_results.py`; cells "
             "with one seed are hints, not findings):"]
    return "\n".join(lines + reward_lines(tables) + auroc_lines(tables))


def run_count(results: Path) -> str:
    """The first line of runs.md: how many of the profile's runs exist and what they have."""
    status = results / "runs.md"
    first = status.read_text().splitlines()[0] if status.exists() else ""
    return first.lstrip("# ").removeprefix("Runs of ").strip()


def main(profile: str | None = None) -> None:
    if profile is None:
        from paper_lib.config import load_run_config

        profile = load_run_config().profile
    results = Path("results") / profile
    tables = results / "tables"
    parts = [f"Runs: {run_count(results)} (the list: `{results / 'runs.md'}`).",
             f"### Reward (Table 1)\n\n{(tables / 'rewards.md').read_text().strip()}",
             f"### Reward against the paper\n\n{(tables / 'paper_vs_us_rewards.md').read_text().strip()}",
             f"### OOD detection, ROC-AUC (Table 2), perturbed states\n\n{(tables / 'ood_auroc_perturbed.md').read_text().strip()}",
             f"### OOD detection, ROC-AUC, noise states (2x ID std)\n\n{(tables / 'ood_auroc_noise.md').read_text().strip()}",
             reading(tables)]
    readme = Path("README.md").read_text()
    head, _, rest = readme.partition(START)
    _, _, tail = rest.partition(END)
    if not rest:
        raise SystemExit(f"README.md has no {START} marker")
    Path("README.md").write_text(head + START + "\n\n" + "\n\n".join(parts) + "\n\n" + END + tail)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
