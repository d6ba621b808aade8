"""Shared test settings for every tests/<layer>/ folder: one torch thread (CI has 2 cores), small real agents,
and the `slow` marker."""

import os
from pathlib import Path

import pytest
import torch as th

os.environ.setdefault("MPLBACKEND", "Agg")
th.set_num_threads(1)

#: Rollout and update sizes small enough for a few hundred steps of real training.
TINY = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}


@pytest.fixture
def tiny_overrides() -> dict:
    return dict(TINY)


#: Modules whose tests train, run notebooks or the pipeline, or replay episodes (a minute and more each):
#: `pytest -m "not slow"` (the inner loop, docs/pipeline.md) leaves them to the whole suite, which CI runs.
#: Named by file name without its tests/<layer>/ folder (basenames are unique across tests/).
SLOW_MODULES = {"test_pipeline", "test_faults", "test_guard", "test_study", "test_notebooks", "test_independent_ensembles",
                "test_bench", "test_spawn", "test_value_level", "test_door_checks_entry", "test_train_queue",
                "test_gpu_runs", "test_atari_head", "test_ood_atari", "test_evaluate_agent", "test_collect",
                "test_train", "test_training_numerics", "test_bad_inputs", "test_ood_coverage", "test_verify",
                "test_lab", "test_site", "test_score_provenance", "test_ensembles_provenance"}


def pytest_collection_modifyitems(config, items) -> None:
    stale = SLOW_MODULES - {path.stem for path in Path(__file__).parent.glob("*/test_*.py")}
    if stale:  # a renamed or deleted module would otherwise drop out of the slow set unnoticed
        raise pytest.UsageError(f"tests/conftest.py SLOW_MODULES names no test file: {sorted(stale)}")
    for item in items:
        if item.module.__name__.rsplit(".", 1)[-1] in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
