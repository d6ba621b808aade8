"""Every run's PEDM-protocol files as notebook 14 reads them (issue 69): the long form behind its table.

`pedm_stage` writes and checks one run's files; this module gathers them for the `pedm_protocol` stage, apart from
`pedm_stage` so the per-run `pedm` stages do not depend on the reporting code. The metrics.csv columns are the
stage's; the delays, the time-matched AUROC and the clock's rows are computed here from each run's steps.npz
(`pedm_scores.step_metrics`), so a change to how they are read replays no run.
"""

from __future__ import annotations

import pandas as pd

from paper_lib.pipeline.config import RunConfig
from paper_lib.pipeline.pedm_stage import pedm_dir, read_metrics, read_run_settings, steps_frame
from paper_lib.reporting.pedm_table import RUN_COLUMNS
from paper_lib.scoring.pedm_scores import CLOCK, STEP_COLUMNS, step_metrics

KEYS = ["env", "method", "seed", "scorer", "kind", "severity"]


def run_step_metrics(cfg: RunConfig, env_id: str, method: str, seed: int) -> pd.DataFrame:
    """`pedm_scores.step_metrics` of one run's steps.npz, with its env, method and seed; one error naming the stage
    to run again where the file is missing or not the stage's."""
    path = pedm_dir(cfg, env_id, method, seed) / "steps.npz"
    try:
        steps, conditions = steps_frame(path)
    except (OSError, ValueError, KeyError) as err:
        raise ValueError(f"{path} is not a readable steps.npz of the `pedm` stage ({err}); run it again "
                         f"(`dvc repro -s pedm@{env_id}-{method}-{seed}`)") from None
    return step_metrics(steps, conditions).assign(env=env_id, method=method, seed=seed)


def protocol_runs(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> pd.DataFrame:
    """`pedm_table.RUN_COLUMNS` of every run among `runs` whose `pedm` stage ran (`read_metrics`: a cut or foreign
    metrics.csv is one error naming `dvc repro -s pedm@...`), each scorer's row completed from its steps.npz
    (`run_step_metrics`), and the clock's rows after the run's scorers; empty, with these columns, where none has."""
    metrics = read_metrics(cfg, runs)
    parts = []
    for (env, method, seed), run in metrics.groupby(["env", "method", "seed"], sort=False):
        computed = run_step_metrics(cfg, env, method, int(seed))
        own = run.merge(computed[computed["scorer"] != CLOCK][[*KEYS, *STEP_COLUMNS]], on=KEYS, how="left",
                        validate="one_to_one")
        parts += [own, computed[computed["scorer"] == CLOCK]]
    metrics = pd.concat(parts, ignore_index=True) if parts else metrics.reindex(columns=[*metrics.columns,
                                                                                           *STEP_COLUMNS])
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
