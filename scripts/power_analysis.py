"""The pre-registration's power analysis: how many seeds each claim needs, from the seeds committed before it.

    python scripts/power_analysis.py            write data/preregistration/power.{csv,md} (params.yaml's power_file)
                                                and its summary into docs/preregistration.md
    python scripts/power_analysis.py --check    recompute and compare with the committed file; exit 1 if it differs

It reads only the seeds params.yaml's `preregistration.power_seeds` names per env family (those committed before
the registration: MuJoCo 0-2, Atari 0), from the committed per-run files: the reward episodes (tables/reward_episodes.csv), each run's
per-seed metrics.csv, the member runs' common-state scores (the AUROC order reads those), and the spawn
experiment's summary. Seeds landing later do not change its output, so
`--check` (tests/reporting/test_preregistration.py) confirms the file on any later commit. The claims table
(notebook 6) reads the file; it is never rebuilt by `make reproduce`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from paper_lib.pipeline.common_states import read_common  # noqa: E402
from paper_lib.pipeline.config import load_run_config, read_params  # noqa: E402
from paper_lib.pipeline.layout import common_runs  # noqa: E402
from paper_lib.reporting.claims import AUROC_ORDER_PAIRS, SPREAD_MEASURES  # noqa: E402
from paper_lib.reporting.paper_tables import _is_detector, best_detectors  # noqa: E402
from paper_lib.reporting.preregistration import Preregistration, family_of, power_table  # noqa: E402
from paper_lib.reporting.tables import csv_text  # noqa: E402


def per_seed_metrics(cfg) -> pd.DataFrame:
    """Every committed run's metrics.csv of the active profile, one frame (env, method, seed columns included)."""
    frames = [pd.read_csv(path) for env, method, seed in cfg.runs()
              if (path := cfg.layout.scores_dir(env, method, seed) / "metrics.csv").exists()]
    if not frames:
        raise SystemExit("error: no run has a metrics.csv: run from a clone with the committed results.")
    return pd.concat(frames, ignore_index=True)


def build(root: Path = ROOT) -> pd.DataFrame:
    cfg = load_run_config()
    prereg = Preregistration.from_params(read_params(root / "params.yaml"))
    metrics = per_seed_metrics(cfg)
    metrics = prereg.power_rows(metrics)
    episodes = pd.read_csv(cfg.layout.reward_episodes)
    spawn_path = cfg.layout.spawn_file("summary")
    spawn = pd.read_csv(spawn_path) if spawn_path.exists() else None
    scored = [run for run in cfg.runs() if run[2] in prereg.power_seeds[family_of(run[0])]
              and (cfg.layout.scores_dir(*run) / "metrics.csv").exists()]
    common, _ = read_common(cfg, common_runs(scored))  # the states the AUROC-order claim reads
    return power_table(episodes, metrics, spawn, prereg, AUROC_ORDER_PAIRS, SPREAD_MEASURES, _is_detector,
                       best_detectors(metrics), common)


def markdown(table: pd.DataFrame) -> str:
    shown = table.assign(decide_at_planned=table["decide_at_planned"].map(lambda p: "" if pd.isna(p) else f"{p:.2f}"),
                         seeds_needed=table["seeds_needed"].map(lambda n: "" if pd.isna(n) else f"{int(n)}"))
    return shown.to_markdown(index=False) + "\n"


DOC = ROOT / "docs" / "preregistration.md"
MARKERS = ("<!-- power summary: scripts/power_analysis.py -->", "<!-- /power summary -->")
SUMMARY_CLAIMS = {"masksembles_reward": "keeps the reward", "auroc_order": "AUROC order", "levitation": "levitation (Ant)",
                  "members_vs_detectors": "beats the best detector"}


def summary(table: pd.DataFrame) -> str:
    """The MuJoCo counts as a claims x envs table for docs/preregistration.md."""
    envs = ["HalfCheetah-v5", "Ant-v5", "Walker2d-v5", "Swimmer-v5"]
    lines = ["| claim | " + " | ".join(e.removesuffix("-v5") for e in envs) + " |", "|---" * (len(envs) + 1) + "|"]
    for claim, name in SUMMARY_CLAIMS.items():
        cells = []
        for env in envs:
            row = table[(table["claim"] == claim) & (table["env"] == env)]
            if row.empty:
                cells.append("")
            elif pd.isna(row["seeds_needed"].iloc[0]):
                cells.append(str(row["note"].iloc[0]).replace(" seeds", ""))
            else:
                cells.append(f"{int(row['seeds_needed'].iloc[0])}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def pasted(doc: str, table: pd.DataFrame) -> str:
    start, end = doc.index(MARKERS[0]) + len(MARKERS[0]), doc.index(MARKERS[1])
    return doc[:start] + "\n" + summary(table) + "\n" + doc[end:]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="compare with the committed file instead of writing")
    args = parser.parse_args(argv)
    prereg = Preregistration.from_params(read_params(ROOT / "params.yaml"))
    path = ROOT / prereg.power_file
    table = build()
    text = csv_text(table)
    doc = DOC.read_text()
    if args.check:
        if not path.exists() or path.read_text() != text:
            print(f"error: {path} differs from what the committed seeds {prereg.power_seeds} give", file=sys.stderr)
            return 1
        if pasted(doc, table) != doc:
            print(f"error: {DOC}'s power summary differs from {path}", file=sys.stderr)
            return 1
        print(f"{path}: the same as recomputed from seeds {prereg.power_seeds}")
        return 0
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.with_suffix(".md").write_text(markdown(table))
    DOC.write_text(pasted(doc, table))
    print(f"wrote {path} and its .md ({len(table)} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
