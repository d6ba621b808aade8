"""Per-run rows an experiment computes once, where the run lands, and keeps while the run's inputs stay.

Two experiments make numbers that move across CPUs: `spawn` plays episodes (MuJoCo differs in the last bits and the
episodes are chaotic) and `value_level` repeats torch's arithmetic, whose last bits differ between CPUs' kernels. Both
run again whenever a run lands, so recomputing every run would move the committed runs' numbers, and the claims that
read them, each time. Instead a folder keeps, beside its per-run tables, `RECORD` (env, method, seed, fingerprint):
a run's rows are read back while its fingerprint (its input files' SHA-256, the settings, the module's `ROWS_VERSION`)
is the one they were computed from; a new, retrained or recollected run is computed. A folder without `RECORD` holds
rows committed before it existed, made from the files committed with them (dvc.lock recorded the stage over them):
they are taken as made from today's. Delete the folder to compute every run again.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

RECORD = "kept_runs.csv"
Run = tuple[str, str, int]


def fingerprint(files: list[Path], settings: dict[str, Any]) -> str:
    """One SHA-256 over the files' bytes (those that exist; a missing optional file counts as missing) and the
    settings: what a run's rows are computed from."""
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode())
    for path in files:
        digest.update(path.name.encode() + (hashlib.sha256(path.read_bytes()).digest() if path.is_file() else b"-"))
    return digest.hexdigest()


@dataclass
class KeptRows:
    tables: dict[str, dict[Run, pd.DataFrame]]  # table name -> run -> its committed rows (runs kept in every table)
    record: pd.DataFrame  # RECORD's rows for every run asked about, as they are once the others are computed

    def has(self, run: Run) -> bool:
        return all(run in rows for rows in self.tables.values())


def kept_rows(folder: Path, tables: tuple[str, ...], fingerprints: dict[Run, str]) -> KeptRows:
    """The committed rows of `tables` (folder/<name>.csv, keyed by env, method, seed) of the runs of `fingerprints`
    whose recorded fingerprint is today's; a run is kept only where every table has its rows."""
    record = pd.DataFrame([{"env": env, "method": method, "seed": seed, "fingerprint": value}
                           for (env, method, seed), value in fingerprints.items()],
                          columns=["env", "method", "seed", "fingerprint"])
    paths = {name: folder / f"{name}.csv" for name in tables}
    if not all(path.is_file() for path in paths.values()):
        return KeptRows({name: {} for name in tables}, record)
    committed = pd.read_csv(folder / RECORD) if (folder / RECORD).is_file() else record
    unchanged = set(committed.merge(record)[["env", "method", "seed"]].itertuples(index=False, name=None))
    kept = {}
    for name, path in paths.items():
        frame = pd.read_csv(path)
        kept[name] = {(env, method, int(seed)): rows.reset_index(drop=True)
                      for (env, method, seed), rows in frame.groupby(["env", "method", "seed"], sort=False)
                      if (env, method, int(seed)) in unchanged}
    everywhere = set.intersection(*(set(rows) for rows in kept.values())) if kept else set()
    return KeptRows({name: {run: rows[run] for run in everywhere} for name, rows in kept.items()}, record)
