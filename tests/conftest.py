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


#: The longest modules, longest first (test-seconds measured on 2026-11-28 with `--durations=0`, 2 cores beside two
#: training runs: test_pipeline 281 s, test_study 143 s, then 45 s down to 15 s). `make test` hands whole modules to
#: its two workers (`--dist loadfile`) in collection order (`--no-loadscope-reorder`; xdist's own reorder puts the
#: modules with the most tests first, which left these two for the end): starting the longest first keeps one worker
#: from running test_study alone at the end while the other idles. Every other module follows, in its usual order.
LONGEST_FIRST = ("test_pipeline", "test_study", "test_door_checks_entry", "test_notebooks", "test_gpu_runs",
                 "test_guard", "test_faults", "test_site", "test_train", "test_bench", "test_score_provenance",
                 "test_ensembles_provenance", "test_independent_ensembles", "test_lab", "test_bad_inputs",
                 "test_fast_inference", "test_methods")


def _module_name(item: pytest.Item) -> str:
    return item.module.__name__.rsplit(".", 1)[-1]


def pytest_collection_modifyitems(config, items) -> None:
    stems = {path.stem for path in Path(__file__).parent.glob("*/test_*.py")}
    for name, listed in (("SLOW_MODULES", SLOW_MODULES), ("LONGEST_FIRST", set(LONGEST_FIRST))):
        stale = listed - stems
        if stale:  # a renamed or deleted module would otherwise drop out of the list unnoticed
            raise pytest.UsageError(f"tests/conftest.py {name} names no test file: {sorted(stale)}")
    for item in items:
        if _module_name(item) in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(_module_name(item), len(rank)))  # stable: a module's tests keep their order
