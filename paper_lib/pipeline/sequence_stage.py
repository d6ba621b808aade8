"""The sequence detectors on one MuJoCo run's main dataset (issue 69): the `sequence_score` stage of dvc.yaml.

    python -m paper_lib.pipeline.sequence_stage HalfCheetah-v5 masksembles 0

The DEEDEE-style episode mean and the DEXTER-style window forest (`scoring.sequence_scores`) score the run's
committed dataset: Table 2's states, split, noised and resampled exactly as the `score` stage does with the run's
seed, so their AUROCs sit beside every other measure's. A stage of its own, not a part of `score`: that stage's
files stay as they are (rescoring every run with every member measure is not needed for two detectors that read only
the states), and this one needs no checkpoint. It reads the dataset alone and steps no env, so `make reproduce` runs
it where stale. Files, in results/<profile>/sequence_scores/<env>/<method>/seed<s>/:

    metrics.csv      per (OOD set, detector): the `score` stage's metric columns (AUROC with its cluster-bootstrap
                     interval: clusters = ID episodes and OOD conditions), tagged env, method, seed
    replicates.npy   the AUROC bootstrap replicates, row i for metrics.csv row i (as the `score` stage's)
    provenance.json  the run and the SHA-256 of the dataset the scores were made from

Cost: about 20 CPU-seconds per run (HalfCheetah, 7000 states; docs/deviations.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from paper_lib.agents.training import stage_lock
from paper_lib.common.io import atomic_dir, write_json_atomic
from paper_lib.pipeline.config import RunConfig
from paper_lib.pipeline.layout import SEQUENCE_STAGE, sequence_runs, stage_suffix
from paper_lib.pipeline.run_cli import run_stage_main
from paper_lib.pipeline.run_results import (PROVENANCE_FILE, _csv, _replicate_matrix, check_dataset_identity,
                                             load_run_dataset, provenance_record, read_peer_scores, run_identity)

FILES = ("metrics.csv", "replicates.npy", PROVENANCE_FILE)


def _rerun(env_id: str, method: str, seed: int) -> str:
    return f"run the stage again (`dvc repro -s {SEQUENCE_STAGE}@{stage_suffix(env_id, method, seed)}`)"


def _inputs(cfg: RunConfig, env_id: str, method: str, seed: int) -> dict[str, Path]:
    return {"dataset": cfg.dataset_path(env_id, method, seed)}


def run_sequence_scores(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    """Score one MuJoCo run's dataset with both sequence detectors; write FILES at once."""
    from paper_lib.scoring.sequence_scores import score_sequences

    if not sequence_runs([(env_id, method, seed)]):
        raise ValueError(f"the sequence detectors score the MuJoCo runs' vector states; {env_id} is not a MuJoCo env")
    path = cfg.dataset_path(env_id, method, seed)
    data = load_run_dataset(path, env_id, method, seed)
    check_dataset_identity(data.metadata, path, env_id, method, seed)
    identity = run_identity(env_id, method, seed)
    out = cfg.layout.sequence_scores_dir(env_id, method, seed)
    with stage_lock(out, "scoring with the sequence detectors"):
        provenance = provenance_record(identity, _inputs(cfg, env_id, method, seed))
        scored = score_sequences(data, seed, cfg.n_bootstrap)
        with atomic_dir(out) as tmp:
            (tmp / "metrics.csv").write_text(_csv(scored.metrics.assign(**identity)))
            np.save(tmp / "replicates.npy", _replicate_matrix(scored.metrics, scored.replicates))
            write_json_atomic(tmp / PROVENANCE_FILE, provenance)
    return out


def read_sequence_scores(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> tuple[pd.DataFrame, dict]:
    """The sequence detectors' (metrics, replicates) of the runs among `runs` whose stage has run
    (`run_results.read_peer_scores`)."""
    return read_peer_scores(sequence_runs(runs), lambda run: cfg.layout.sequence_scores_dir(*run),
                            lambda run: _inputs(cfg, *run), lambda run: _rerun(*run))


def main(argv: list[str] | None = None) -> None:
    run_stage_main(argv, __doc__.splitlines()[0], lambda cfg, env_id, method, seed, params: run_sequence_scores(
        cfg, env_id, method, seed))


if __name__ == "__main__":
    main()
