"""Every run's PEDM-protocol files as notebook 14 reads them (issue 69): the long form behind its table.

`pedm_stage` writes and checks one run's files; this module gathers them for the `pedm_protocol` stage, apart from
`pedm_stage` so the per-run `pedm` stages do not depend on the reporting code.
"""

from __future__ import annotations

import pandas as pd

from paper_lib.pipeline.config import RunConfig
from paper_lib.pipeline.pedm_stage import read_metrics, read_run_settings
from paper_lib.reporting.pedm_table import RUN_COLUMNS


def protocol_runs(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> pd.DataFrame:
    """`pedm_table.RUN_COLUMNS` of every run among `runs` whose `pedm` stage ran (`read_metrics`: a cut or foreign
    metrics.csv is one error naming `dvc repro -s pedm@...`); empty, with these columns, where none has."""
    metrics = read_metrics(cfg, runs)
    out = metrics[list(RUN_COLUMNS)].copy()
    if len(out):
        out["seed"] = out["seed"].astype(int)
    return out.reset_index(drop=True)


def protocol_settings(cfg: RunConfig, runs: pd.DataFrame) -> dict[str, list]:
    """{setting: its distinct values over the runs in `runs`}, from each run's provenance.json (what the stage ran
    with: PEDM's epochs, episodes per kind and severity, ...)."""
    found: dict[str, set] = {}
    for env, method, seed in runs[["env", "method", "seed"]].drop_duplicates().itertuples(index=False):
        for name, value in read_run_settings(cfg, env, method, int(seed)).items():
            found.setdefault(name, set()).add(value)
    return {name: sorted(values, key=str) for name, values in found.items()}
