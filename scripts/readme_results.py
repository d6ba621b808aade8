"""Paste the pipeline's tables into the README and the docs pages, each file written all or nothing.

Numbers in the README and docs/ must be the pipeline's: this copies results/<profile>/tables/*.md between
marker pairs (nothing typed by hand), one pair per place (every path of results/<profile>/ from
paper_lib.pipeline.layout):
- `<!-- headline:start -->` / `<!-- headline:end -->` in README.md: the one headline table
  (`HEADLINE_TABLE`, Table 2's perturbed-state AUROC);
- `<!-- results:start -->` / `<!-- results:end -->` in docs/results.md: every results table, with the run
  count from results/<profile>/runs.md and a short reading computed from the same tables. Works on a partial
  matrix: cells of runs not trained yet are NaN in the tables and left out of the reading;
- `<!-- bench:start -->` / `<!-- bench:end -->` in docs/benchmarks.md: the benchmark's cost ratios
  (results/bench/bench.csv, `make bench`), and `<!-- limits:start -->` / `<!-- limits:end -->` its times over
  their arithmetic limits;
- `<!-- probes:start -->` / `<!-- probes:end -->` in docs/deviations.md: the recipe probes
  (results/recipe_probes/summary_by_variant.csv).
Every file is pasted in memory first (a missing marker stops the script before anything is written), then
each is written to a temporary file beside it and moved over it (`os.replace`), so a failure never leaves a
truncated README or page.
    python scripts/readme_results.py [PROFILE]     # default: the active profile of params.yaml
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

import pandas as pd

from paper_lib.measures.definitions import MEMBER_MEASURES
from paper_lib.pipeline.layout import Layout

README = Path("README.md")
RESULTS_PAGE = Path("docs/results.md")
BENCH_PAGE = Path("docs/benchmarks.md")
DEVIATIONS_PAGE = Path("docs/deviations.md")
HEADLINE_START, HEADLINE_END = "<!-- headline:start -->", "<!-- headline:end -->"
#: The README's one headline table, a table of results/<profile>/tables/ (its Markdown file is pasted).
HEADLINE_TABLE = "ood_auroc_perturbed"
START, END = "<!-- results:start -->", "<!-- results:end -->"
BENCH_START, BENCH_END = "<!-- bench:start -->", "<!-- bench:end -->"
PROBES_START, PROBES_END = "<!-- probes:start -->", "<!-- probes:end -->"
PROBES_CSV = Path("results/recipe_probes/summary_by_variant.csv")
#: The probe table's columns: (summary_by_variant column, header in docs/deviations.md).
PROBE_COLUMNS = (("seeds", "seeds"), ("train@100k", "100k"), ("train@200k", "200k"), ("train@300k", "300k"),
                 ("train@500k", "500k"), ("train@1000k", "1e6"), ("train@2000k", "2e6"),
                 ("eval_deterministic", "eval det."), ("eval_sampled", "eval sampled"),
                 ("train@300k per seed", "300k per seed"))
BENCH_METHODS = ("masksembles", "mc_dropout", "mc_dropconnect", "ensemble")
#: Rows of the benchmark table in docs/benchmarks.md: (env, measurement, label).
BENCH_ROWS = (
    ("HalfCheetah-v5", "train_steps_per_s", "HalfCheetah training"),
    ("SeaquestNoFrameskip-v4", "train_steps_per_s", "Seaquest training"),
    ("HalfCheetah-v5", "act_uncertainty_b1",
     "HalfCheetah, one state: action + every measure (`act_with_uncertainty`) vs plain `predict`"),
    ("SeaquestNoFrameskip-v4", "act_uncertainty_b1", "Seaquest, the same"),
    ("HalfCheetah-v5", "uncertainty_b4096",
     "HalfCheetah, every measure on 4096 states vs a plain `predict` of them (issue target: Masksembles 2x, see below)"),
    ("SeaquestNoFrameskip-v4", "uncertainty_b4096", "Seaquest, the same"),
    ("SeaquestNoFrameskip-v4", "rss_increase_infer_mb",
     "Seaquest, peak memory scoring 4096 states, above the process (issue target: 1.5x)"),
)
#: Rows of the time-over-limit table in docs/benchmarks.md (issue 70): (env, measurement, label).
LIMIT_ROWS = (
    ("HalfCheetah-v5", "act_uncertainty_b1", "HalfCheetah, one state, action + every measure (`act_with_uncertainty`)"),
    ("HalfCheetah-v5", "compiled_act_uncertainty_b1", "HalfCheetah, one state, the same compiled (`compile_policy`)"),
    ("HalfCheetah-v5", "uncertainty_b4096", "HalfCheetah, every measure on 4096 states"),
    ("SeaquestNoFrameskip-v4", "act_uncertainty_b1", "Seaquest, one state, action + every measure"),
    ("SeaquestNoFrameskip-v4", "uncertainty_b4096", "Seaquest, every measure on 4096 states"),
)
LIMITS_START, LIMITS_END = "<!-- limits:start -->", "<!-- limits:end -->"
FREE_PREFIXES = ("mahalanobis", "knn")
#: A Markdown table's cell border: a pipe that is not escaped.
CELL_BORDER = re.compile(r"(?<!\\)\|")


def _refuse(path: Path, problem: str) -> None:
    """One error naming the table and the fix; raised while pasting in memory, so no file is written."""
    raise SystemExit(f"{path} {problem}; run the stage that writes it again (`make reproduce`, or `git checkout "
                     f"{path}` for the committed copy): nothing was written")


def table_csv(path: Path) -> pd.DataFrame:
    """A committed table's CSV, refused when missing or cut off (its last line ends mid-row or it holds no row)."""
    if not path.is_file():
        _refuse(path, "is missing")
    text = path.read_text(encoding="utf-8")
    if not text.endswith("\n"):
        _refuse(path, "is incomplete (cut off?): its last line ends mid-row")
    try:
        return pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        _refuse(path, f"is not a readable CSV ({type(err).__name__}: {err})")
        raise  # unreachable: for type checkers


def table_md(path: Path) -> str:
    """A committed Markdown table, whole: every row as wide as its header and as many rows as its CSV holds.

    A truncated .md pasted as it is would replace a table of eight rows with one, without a word."""
    if not path.is_file():
        _refuse(path, "is missing")
    text = path.read_text(encoding="utf-8").strip()
    rows = [line for line in text.splitlines() if line.startswith("|")]
    widths = [len(CELL_BORDER.findall(row)) for row in rows]  # a pipe inside a cell is escaped (\\|)
    if len(rows) < 2 or any(not row.endswith("|") or width != widths[0] for row, width in zip(rows, widths)):
        _refuse(path, "is incomplete (cut off?): its table has a row cut short or no header")
    csv = path.with_suffix(".csv")
    if csv.exists() and len(table_csv(csv)) != len(rows) - 2:
        _refuse(path, f"is incomplete (cut off?): its table has {len(rows) - 2} rows but {csv.name} has "
                      f"{len(table_csv(csv))}")
    return text


def _range(values: pd.Series) -> str:
    values = values.dropna()
    return f"{values.min():.2f}-{values.max():.2f}" if len(values) else "n/a"


def reward_lines(layout: Layout) -> list[str]:
    """Ours against the paper, per run cell that exists (sampled actions, as the paper's Table 1)."""
    vs = table_csv(layout.table("paper_vs_us_rewards", "csv")).dropna(subset=["ours"])
    lines = []
    for env, rows in vs.groupby("env", sort=False):
        cells = [f"{r.method} ({r.inference}) {r.ours:.0f} vs {r.paper:.0f}" for r in rows.itertuples()]
        lines.append(f"- **{env}, reward ours (sampled) vs the paper:** " + "; ".join(cells) + ".")
    return lines


def auroc_lines(layout: Layout) -> list[str]:
    """Per env: member measures against member-free detectors on perturbed states, and the paper's cells."""
    auroc = table_csv(layout.table("ood_auroc_perturbed", "csv"))
    paper = table_csv(layout.table("paper_vs_us_auroc", "csv"))
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


def verdict_lines(layout: Layout) -> list[str]:
    """Per claim of notebook 6: in which envs it holds, does not hold, or is inconclusive."""
    path = layout.table("paper_claims", "csv")
    if not path.exists():
        return []
    claims = table_csv(path)
    lines = []
    for claim, rows in claims.groupby("claim", sort=False):
        by_verdict = rows.groupby("verdict", sort=False)["env"].agg(lambda envs: ", ".join(envs))
        lines.append(f"- **{claim}:** " + "; ".join(f"{verdict} ({envs})" for verdict, envs in by_verdict.items()) + ".")
    return lines


def reading(layout: Layout) -> str:
    lines = ["### What these numbers say", "",  # a heading of its own: a reader looks for the reading
             "Computed from the tables above by `scripts/readme_results.py` (cells "
             "with one seed are hints, not findings). The verdicts of notebook 6 (one rule for every claim: holds "
             "when the 95% interval excludes failure, does not hold when it excludes success, otherwise undecided; "
             "where one of several cells would decide, that cell's interval is simultaneous over them; an env short "
             "of its registered seeds reads provisional, an undecided cell the registered power analysis sized "
             "beyond the plan undecidable: docs/preregistration.md):"]
    return "\n".join(lines + verdict_lines(layout) + ["", "The numbers behind them:"] + reward_lines(layout)
                     + auroc_lines(layout))


def repeated_games_line(layout: Layout) -> str:
    """Notebook 2's count of the run x mode groups that replay a game, from the episodes it wrote ('' before it did)."""
    from paper_lib.reporting.paper_tables import repeated_games, repeated_games_note

    path = layout.reward_episodes
    if not path.exists():
        return ""
    episodes = table_csv(path)
    return (f"\n\nRepeated games (notebook 2, `reward_repeated_games.md`): "
            f"{repeated_games_note(repeated_games(episodes), episodes)}")


def run_count(layout: Layout) -> str:
    """The first line of runs.md: how many of the profile's runs exist and what they have."""
    status = layout.status_file
    first = status.read_text().splitlines()[0] if status.exists() else ""
    return first.lstrip("# ").removeprefix("Runs of ").strip()


def training_time(layout: Layout) -> str:
    """runs.md's training wall time and its estimate for the missing runs (`pipeline_status`), or ''."""
    status = layout.status_file
    lines = status.read_text().splitlines() if status.exists() else []
    return " ".join(line for line in lines if line.startswith("Training wall time")
                    or (line.startswith("The ") and "without a checkpoint need about" in line))


def bench_table(csv: Path) -> str:
    """The methods' cost ratios against plain SB3 PPO, one row per `BENCH_ROWS` entry, bold where a target is met."""
    bench = table_csv(csv)
    lines = ["| | " + " | ".join({"masksembles": "Masksembles", "mc_dropout": "MC Dropout",
                                   "mc_dropconnect": "MC DropConnect", "ensemble": "Ensemble (k=4)"}[m]
                                  for m in BENCH_METHODS) + " | target |", "|---" * (len(BENCH_METHODS) + 2) + "|"]
    for env, measurement, label in BENCH_ROWS:
        rows = bench[(bench.env_id == env) & (bench.measurement == measurement)].set_index("method")
        cells, targets = [], {}
        for method in BENCH_METHODS:
            if method not in rows.index:
                cells.append("-")
                continue
            row = rows.loc[method]
            met = row.meets_target == "yes"
            cells.append(f"**{row.ratio_to_baseline:.2f}x**" if met else f"{row.ratio_to_baseline:.2f}x")
            if pd.notna(row.target):
                targets[method] = f"{row.target:g}x"
        common = targets.get(BENCH_METHODS[0], "-")
        others = "; ".join(f"{m} {t}" for m, t in targets.items() if t != common)
        target = common + (f" ({others})" if others else "")
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {target} |")
    return "\n".join(lines)


def limit_table(csv: Path) -> str:
    """Each method's time over its arithmetic limit (bench.csv's `time_over_limit`), one row per `LIMIT_ROWS` entry;
    "-" where the method has no such timing (the compiled call covers Masksembles and Ensemble MLPs only)."""
    bench = table_csv(csv)
    methods = ("baseline", *BENCH_METHODS)
    lines = ["| time / limit | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
    for env, measurement, label in LIMIT_ROWS:
        rows = bench[(bench.env_id == env) & (bench.measurement == measurement)].set_index("method")
        cells = [f"{rows.loc[m].time_over_limit:.2f}x" if m in rows.index and pd.notna(rows.loc[m].time_over_limit)
                 else "-" for m in methods]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def probe_table(csv: Path) -> str:
    """Every recipe probe's training reward (mean over its seeds) and final evaluation, one row per probe."""
    probes = table_csv(csv)
    cell = lambda v: "-" if pd.isna(v) else v if isinstance(v, str) else f"{v:.0f}"
    lines = ["| probe (env/variant) | " + " | ".join(h for _, h in PROBE_COLUMNS) + " |",
             "|---" * (len(PROBE_COLUMNS) + 1) + "|"]
    lines += ["| " + " | ".join([row["probe"]] + [cell(row[c]) for c, _ in PROBE_COLUMNS]) + " |"
              for _, row in probes.iterrows()]
    return "\n".join(lines)


def value_level_part(layout: Layout) -> str:
    """Notebook 13's table with its computed reading: how much of value std's AUROC is the value level."""
    from paper_lib.experiments.value_level import value_level_reading

    lines = value_level_reading(table_csv(layout.table("value_level", "csv")))
    return (f"### Is value uncertainty more than a low value? (notebook 13, beyond the paper)\n\n"
            f"{table_md(layout.table('value_level', 'md'))}\n\n" + "\n".join(f"- {line}" for line in lines))


def independent_part(layout: Layout) -> str:
    """Notebook 11's independent ensembles beside the paper's appendix B.2 numbers, and its generated reading."""
    ensembles = layout.table_folder("ensembles")
    table = table_md(ensembles / "ensembles_independent_vs_paper.md")
    reading = (ensembles / "ensembles_independent_reading.md").read_text().strip().split("\n\n", 1)[-1]
    return f"### Independently trained ensembles against the paper (notebook 11, appendix B.2)\n\n{table}\n\n{reading}"


def own_vs_shared_part(layout: Layout) -> str:
    """Notebook 11's own-vs-shared table and its generated reading."""
    ensembles = layout.table_folder("ensembles")
    table = table_md(ensembles / "ensembles_own_vs_shared.md")
    reading = (ensembles / "ensembles_own_vs_shared_reading.md").read_text().strip().split("\n\n", 1)[-1]
    return f"### Does keeping each member on-policy help? `own` vs `shared` (notebook 11, beyond the paper)\n\n{table}\n\n{reading}"


def study_part(layout: Layout) -> str:
    """Notebook 9's reading as it stands: the sweep's progress (in the caption) and each env's leaders."""
    study = layout.table_folder("study")
    return (f"### The study: the most performant configurations (notebook 9)\n\n"
            f"{(study / 'study_reading.md').read_text().strip()}\n\n"
            f"An env is read once all its studies reached their trial target; `_members` columns leave out the "
            f"baseline, whose member-free detector is the reference point. Per-study counts: "
            f"`{study / 'study_summary.md'}`."
            + _other_algorithms_part(layout))


def _other_algorithms_part(layout: Layout) -> str:
    """Notebook 9's check of appendix C's A2C/TRPO readings, once those studies are read."""
    versus = layout.table_folder("study") / "study_other_algs_vs_paper.md"
    if not versus.exists() or not len(table_csv(versus.with_suffix(".csv"))):
        return ""
    return f"\n\nA2C and TRPO against appendix C:\n\n{table_md(versus)}"


def scaling_part(layout: Layout) -> str:
    """Notebook 10's comparison with appendix E, once scaling runs are read."""
    scaling = layout.table_folder("scaling")
    return (f"### Scaling the hidden layers against the paper (notebook 10, appendix E)\n\n"
            f"{table_md(scaling / 'scaling_vs_paper.md')}\n\n"
            f"Final rewards per width: `{scaling / 'scaling_final_reward.md'}`.")


def headline_part(layout: Layout) -> str:
    """The README's headline table: the committed `HEADLINE_TABLE` as it is, and the file it comes from."""
    headline = layout.table(HEADLINE_TABLE, "md")
    return f"{table_md(headline)}\n\n(Pasted from `{headline}`.)"


def aggregate_parts(layout: Layout) -> list[str]:
    """Across envs first (the reader's first question): rliable's aggregates of reward and AUROC (notebooks 2, 3)."""
    stems = (("reward_aggregates", "Across envs: reward"), ("reward_improvement", "Across envs: P(more reward)"),
             ("auroc_aggregates", "Across envs: OOD detection"), ("auroc_improvement", "Across envs: P(higher AUROC)"))
    return [f"### {title}\n\n{table_md(layout.table(stem, 'md'))}" for stem, title in stems
            if layout.table(stem, "md").exists()]


def results_part(layout: Layout) -> str:
    """Everything docs/results.md shows between its markers: run count, Tables 1 and 2, the readings."""
    def md(stem: str) -> str:
        return table_md(layout.table(stem, "md"))

    parts = [f"Runs: {run_count(layout)} (the list: `{layout.status_file}`). {training_time(layout)}".strip(),
             *aggregate_parts(layout),
             f"### Reward (Table 1)\n\n{md('rewards')}{repeated_games_line(layout)}",
             f"### Reward against the paper\n\n{md('paper_vs_us_rewards')}",
             f"### OOD detection, ROC-AUC (Table 2), perturbed states\n\n{md('ood_auroc_perturbed')}",
             f"### OOD detection, ROC-AUC, noise states (2x ID std)\n\n{md('ood_auroc_noise')}",
             reading(layout)]
    if layout.table("paper_claims", "md").exists():
        parts.append(f"### The paper's claims, checked (notebook 6)\n\n{md('paper_claims')}")
    if layout.table("value_level", "md").exists():
        parts.append(value_level_part(layout))
    ensembles, study = layout.table_folder("ensembles"), layout.table_folder("study")
    if (ensembles / "ensembles_independent_reading.md").exists():
        parts.append(independent_part(layout))
    if (ensembles / "ensembles_own_vs_shared.md").exists():
        parts.append(own_vs_shared_part(layout))
    if (study / "study_reading.md").exists():
        parts.append(study_part(layout))
    versus = layout.table_folder("scaling") / "scaling_vs_paper.csv"
    if versus.exists() and len(table_csv(versus)):
        parts.append(scaling_part(layout))
    return "\n\n".join(parts)


def paste(text: str, start: str, end: str, body: str, name: Path | str = README) -> str:
    """`text` (the file `name`) with what lies between the `start` and `end` markers replaced by `body`."""
    head, found, rest = text.partition(start)
    if not found or end not in rest:
        raise SystemExit(f"{name} has no {start} ... {end} marker pair: nothing was written")
    _, _, tail = rest.partition(end)
    return head + start + "\n\n" + body + "\n\n" + end + tail


def write_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` all or nothing: a temporary file beside it, moved over it with `os.replace`."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
            out.flush()
            os.fsync(out.fileno())
        shutil.copymode(path, tmp)  # keep the file's permissions, not mkstemp's 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def pastes(profile: str) -> dict[Path, list[tuple[str, str, str]]]:
    """Per file, the (start marker, end marker, body) pairs to paste, from the committed outputs that exist."""
    layout = Layout.of(".", profile)
    todo = {README: [(HEADLINE_START, HEADLINE_END, headline_part(layout))],
            RESULTS_PAGE: [(START, END, results_part(layout))]}
    bench = Path("results/bench/bench.csv")
    if bench.exists():
        todo[BENCH_PAGE] = [(BENCH_START, BENCH_END, bench_table(bench)), (LIMITS_START, LIMITS_END, limit_table(bench))]
    if PROBES_CSV.exists():
        todo[DEVIATIONS_PAGE] = [(PROBES_START, PROBES_END, probe_table(PROBES_CSV))]
    return todo


def active_profile() -> str:
    """The active profile of params.yaml."""
    from paper_lib.pipeline.config import load_run_config

    return load_run_config().profile


def main(profile: str | None = None) -> None:
    if profile is None:
        profile = active_profile()
    pasted = {}
    for path, blocks in pastes(profile).items():  # every file in memory first: a missing marker writes nothing
        text = old = path.read_text(encoding="utf-8")
        for start, end, body in blocks:
            text = paste(text, start, end, body, path)
        pasted[path] = (old, text)
    for path, (old, text) in pasted.items():
        if text != old:
            write_atomic(path, text)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
