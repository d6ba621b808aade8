"""Paste the committed profile's tables into README.md's "Results" section, verbatim.

README numbers must be the pipeline's: this copies results/<profile>/tables/*.md between the markers
`<!-- results:start -->` and `<!-- results:end -->` and computes the few numbers the reading quotes.
    python scripts/readme_results.py cpu
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

START, END = "<!-- results:start -->", "<!-- results:end -->"


def reading(tables: Path) -> str:
    auroc = pd.read_csv(tables / "ood_auroc_perturbed.csv")
    rewards = pd.read_csv(tables / "rewards_long.csv") if (tables / "rewards_long.csv").exists() else None
    cell = auroc.set_index(["method", "measure"])

    def a(method: str, measure: str, env: str) -> str:
        return f"{cell.loc[(method, measure), env]:.2f}"

    paper = pd.read_csv(tables / "paper_vs_us_auroc.csv").set_index(["method", "measure", "env"])["paper"]

    def p(method: str, env: str = "HalfCheetah-v5") -> str:
        return f"{paper[(method, 'value_std', env)]:.2f}/{paper[(method, 'policy_std', env)]:.2f}"

    free = auroc[auroc.measure.str.startswith(("mahalanobis", "knn"))]
    member = auroc[auroc.measure.isin(["value_std", "policy_std", "policy_js"])]
    lines = [
        "What these numbers say (computed from the tables above; one seed, so hints only):",
        f"- **Fixed scoring.** MC DropConnect's HalfCheetah value_std AUROC is {a('mc_dropconnect', 'value_std', 'HalfCheetah-v5')}"
        f" (policy_std {a('mc_dropconnect', 'policy_std', 'HalfCheetah-v5')}) now that every state gets its own masks;"
        " the 0.94 / 0.26 committed before were artifacts of masks shared by a scoring batch.",
        f"- **HalfCheetah:** Masksembles value/policy {a('masksembles', 'value_std', 'HalfCheetah-v5')} / "
        f"{a('masksembles', 'policy_std', 'HalfCheetah-v5')}, Ensemble {a('ensemble', 'value_std', 'HalfCheetah-v5')} / "
        f"{a('ensemble', 'policy_std', 'HalfCheetah-v5')}, MC Dropout {a('mc_dropout', 'value_std', 'HalfCheetah-v5')} / "
        f"{a('mc_dropout', 'policy_std', 'HalfCheetah-v5')} (the paper: {p('masksembles')}, {p('ensemble')}, "
        f"{p('mc_dropout')}).",
        f"- **Member-free detectors** reach {free['HalfCheetah-v5'].min():.2f}-{free['HalfCheetah-v5'].max():.2f} on HalfCheetah "
        f"and {free['Swimmer-v5'].min():.2f}-{free['Swimmer-v5'].max():.2f} on Swimmer, against "
        f"{member['HalfCheetah-v5'].min():.2f}-{member['HalfCheetah-v5'].max():.2f} and "
        f"{member['Swimmer-v5'].min():.2f}-{member['Swimmer-v5'].max():.2f} for the member measures.",
    ]
    return "\n".join(lines)


def main(profile: str) -> None:
    tables = Path("results") / profile / "tables"
    parts = [f"### Reward (Table 1)\n\n{(tables / 'rewards.md').read_text().strip()}",
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
    main(sys.argv[1] if len(sys.argv) > 1 else "cpu")
