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
#: The issue's targets, as cost ratios against plain SB3 PPO with the same network sizes.
TARGETS: dict[tuple[str, str], float] = {
    **{("train_steps_per_s", m): 1.15 for m in ("masksembles", "mc_dropout", "mc_dropconnect")},
    ("train_steps_per_s", "ensemble"): 1.3,
    **{("act_uncertainty_b1", m): 1.5 for m in ("masksembles", "mc_dropout", "mc_dropconnect", "ensemble")},
}
#: Measurements whose ratio is against a different baseline measurement.
_REFERENCE_PREFIX = {"act_uncertainty_b": "predict_b", "uncertainty_b": "predict_b"}


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


def to_csv(rows: list[Row]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[f.name for f in fields(Row)], lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(asdict(row))
    return buffer.getvalue()


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
    targeted = [r for r in rows if r.meets_target]
    if targeted:
        lines += ["## Targets", "", "| env | method | measurement | ratio | target | meets |", "|---|---|---|---|---|---|"]
        lines += [f"| {r.env_id} | {r.method} | {r.measurement} | {r.ratio_to_baseline:.2f}x | {r.target:g}x | "
                  f"{r.meets_target} |" for r in targeted]
        lines.append("")
    return "\n".join(lines)


def write_outputs(rows: list[Row], out_dir: str | Path, header: str) -> tuple[Path, Path, str]:
    """Write bench.csv and bench.md atomically; return both paths and the Markdown text."""
    out = Path(out_dir)
    markdown = to_markdown(rows, header)
    csv_path = write_text_atomic(out / "bench.csv", to_csv(rows))
    md_path = write_text_atomic(out / "bench.md", markdown)
    return csv_path, md_path, markdown
