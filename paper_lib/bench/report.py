"""Rows, ratios against plain SB3 PPO, targets, and the CSV / Markdown outputs.

Every ratio is a cost ratio, method / baseline in time or memory (for a rate in steps/s:
baseline rate / method rate), so ">1" always means "costs more than plain SB3 PPO", and
one target reads the same for training and inference.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

from paper_lib.common.io import write_text_atomic

BASELINE = "baseline"
ENV_ONLY = "env_only"  # the env-stepping ceiling's "method"
RATE_UNIT = "steps/s"
#: Every repetition of every timing, beside bench.csv (the speed claim reads it).
TIMINGS_FILE = "bench_timings.csv"
#: A limit's samples in bench_timings.csv: this prefix before the measurement it bounds.
LIMIT_PREFIX = "limit:"
#: The issue's targets, as cost ratios against plain SB3 PPO with the same network sizes.
TARGETS: dict[tuple[str, str], float] = {
    **{("train_steps_per_s", m): 1.15 for m in ("masksembles", "mc_dropout", "mc_dropconnect")},
    ("train_steps_per_s", "ensemble"): 1.3,
    **{("act_uncertainty_b1", m): 1.5 for m in ("masksembles", "mc_dropout", "mc_dropconnect", "ensemble")},
}
#: `act_uncertainty_b1` on the compiled policy (`paper_lib.deploy`): Masksembles and Ensemble MLPs.
COMPILED_ACT = "compiled_act_uncertainty_b1"
#: Measurements whose ratio is against a different baseline measurement.
_REFERENCE_PREFIX = {"act_uncertainty_b": "predict_b", "uncertainty_b": "predict_b",
                     "compiled_act_uncertainty_b": "predict_b"}


@dataclass(frozen=True)
class Row:
    """One env x method x measurement; the ratio and target fields are filled in by `with_ratios`."""

    env_id: str
    method: str
    measurement: str
    value: float
    unit: str
    samples: int
    settings: str
    ratio_to_baseline: float = math.nan
    reference: str = ""
    target: float = math.nan
    meets_target: str = ""
    torch_threads: int = 1
    machine: str = ""
    load_avg_1m: float = math.nan
    macs_per_state: float = math.nan  # multiply-adds one state needs (`bench.arithmetic`), inference rows
    limit: float = math.nan  # the measured limit: a plain dense computation of that size, same unit (`bench.limits`)
    time_over_limit: float = math.nan  # value / limit: how far from what its arithmetic allows


@dataclass(frozen=True)
class Sample:
    """One repetition of one timing (bench_timings.csv): what an interval over repetitions needs.

    Repetition i of every method's timing was taken in the same interleaved round (the i-th PPO
    iteration for training), so methods pair by repetition.
    """

    env_id: str
    method: str
    measurement: str
    repetition: int
    value: float
    unit: str


def reference_measurement(measurement: str) -> str:
    """The baseline measurement a ratio divides by (uncertainty timings: a plain predict)."""
    if measurement == "env_steps_per_s":
        return "train_steps_per_s"
    for prefix, ref in _REFERENCE_PREFIX.items():
        if measurement.startswith(prefix):
            return ref + measurement[len(prefix):]
    return measurement


def with_ratios(rows: list[Row]) -> list[Row]:
    """Fill ratio_to_baseline, reference, target and meets_target from the same run's baseline rows."""
    baseline = {(r.env_id, r.measurement): r.value for r in rows if r.method == BASELINE}
    out = []
    for row in rows:
        ref_name = reference_measurement(row.measurement)
        ref = baseline.get((row.env_id, ref_name), math.nan)
        if row.unit == RATE_UNIT:
            ratio = ref / row.value if row.value > 0 else math.nan
        else:
            ratio = row.value / ref if ref > 0 else math.nan
        target = TARGETS.get((row.measurement, row.method), math.nan)
        meets = "" if math.isnan(target) or math.isnan(ratio) else ("yes" if ratio <= target else "no")
        out.append(replace(row, ratio_to_baseline=ratio, reference=f"{BASELINE}/{ref_name}", target=target,
                           meets_target=meets))
    return out


def to_csv(rows: list[Row] | list[Sample], kind: type = Row) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[f.name for f in fields(kind)], lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(asdict(row))
    return buffer.getvalue()


def with_limits(rows: list[Row], limits: dict[tuple[str, str, str], tuple[float, float]]) -> list[Row]:
    """Fill macs_per_state, limit and time_over_limit from {(env, method, measurement): (macs, limit)}."""
    out = []
    for row in rows:
        macs, limit = limits.get((row.env_id, row.method, row.measurement), (math.nan, math.nan))
        over = row.value / limit if limit > 0 else math.nan
        out.append(replace(row, macs_per_state=macs, limit=limit, time_over_limit=over))
    return out


def limits_markdown(env_rows: list[Row], methods: list[str]) -> list[str]:
    """One env's inference timings against their limits: time / limit (ratio), and the arithmetic."""
    limited = [r for r in env_rows if not math.isnan(r.limit)]
    if not limited:
        return []
    base_macs = {r.measurement: r.macs_per_state for r in limited if r.method == BASELINE}
    lines = ["Against the arithmetic limit: time / limit in ms (time over limit), and the multiply-adds per state "
             "(x the plain network's for the same measurement). The limit is a plain dense computation of the "
             "method's multiply-adds (and MC mask work), batched at best, timed in this run (`paper_lib/bench/"
             "arithmetic.py`, `limits.py`).", "",
             "| measurement | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for name in dict.fromkeys(r.measurement for r in limited):
        cells = {}
        for r in (r for r in limited if r.measurement == name):
            base = base_macs.get(name, math.nan)
            times = f" ({r.macs_per_state / base:.2f}x)" if base > 0 else ""
            cells[r.method] = (f"{_num(r.value)} / {_num(r.limit)} ({r.time_over_limit:.2f}x); "
                               f"{r.macs_per_state / 1e6:.3g}M MACs{times}")
        lines.append(f"| {name} | " + " | ".join(cells.get(m, "") for m in methods) + " |")
    return lines + [""]


def _num(x: float) -> str:
    return "" if math.isnan(x) else f"{x:.4g}"


def _cell(row: Row) -> str:
    """'value (ratio x)' plus a mark where the row has a target."""
    text = _num(row.value)
    if not math.isnan(row.ratio_to_baseline):
        text += f" ({row.ratio_to_baseline:.2f}x)"
    return text + {"yes": " ✓", "no": " ✗"}.get(row.meets_target, "")


def to_markdown(rows: list[Row], header: str) -> str:
    """Per env, one table (measurement x method), the ceiling, then every targeted ratio."""
    lines = ["# What uncertainty costs, against plain SB3 PPO", "", header, "",
             "Cells: value (cost ratio vs plain SB3 PPO, >1 = slower or more memory); "
             "uncertainty timings are divided by the baseline's plain predict of the same batch. "
             "✓/✗: meets the target or not.", ""]
    for env_id in dict.fromkeys(r.env_id for r in rows):
        env_rows = [r for r in rows if r.env_id == env_id]
        methods = [m for m in dict.fromkeys(r.method for r in env_rows) if m != ENV_ONLY]
        base = next((r for r in env_rows if r.method == BASELINE), env_rows[0])
        lines += [f"## {env_id}", "", f"Settings: {base.settings}", ""]
        for r in (r for r in env_rows if r.method == ENV_ONLY):
            lines += [f"Ceiling, the same vectorized env stepped with random actions: {_num(r.value)} {r.unit}; "
                      f"plain PPO trains at {r.ratio_to_baseline:.0%} of it.", ""]
        lines += ["| measurement | unit | " + " | ".join(methods) + " |", "|---|---|" + "---|" * len(methods)]
        for name in dict.fromkeys(r.measurement for r in env_rows if r.method != ENV_ONLY):
            cells = {r.method: _cell(r) for r in env_rows if r.measurement == name}
            unit = next(r.unit for r in env_rows if r.measurement == name)
            lines.append(f"| {name} | {unit} | " + " | ".join(cells.get(m, "") for m in methods) + " |")
        lines.append("")
        lines += limits_markdown(env_rows, methods)
    targeted = [r for r in rows if r.meets_target]
    if targeted:
        lines += ["## Targets", "", "| env | method | measurement | ratio | target | meets |", "|---|---|---|---|---|---|"]
        lines += [f"| {r.env_id} | {r.method} | {r.measurement} | {r.ratio_to_baseline:.2f}x | {r.target:g}x | "
                  f"{r.meets_target} |" for r in targeted]
        lines.append("")
    return "\n".join(lines)


def write_outputs(rows: list[Row], out_dir: str | Path, header: str, samples: list[Sample] | None = None
                  ) -> tuple[Path, Path, str]:
    """Write bench.csv, bench.md and (given samples) bench_timings.csv atomically; return the first two paths
    and the Markdown text."""
    out = Path(out_dir)
    markdown = to_markdown(rows, header)
    if samples is not None:
        write_text_atomic(out / TIMINGS_FILE, to_csv(samples, Sample))
    csv_path = write_text_atomic(out / "bench.csv", to_csv(rows))
    md_path = write_text_atomic(out / "bench.md", markdown)
    return csv_path, md_path, markdown
