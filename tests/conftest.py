"""Shared test settings: one torch thread (CI has 2 cores), and small real agents."""

import os

import pytest
import torch as th

os.environ.setdefault("MPLBACKEND", "Agg")
th.set_num_threads(1)

#: Rollout and update sizes small enough for a few hundred steps of real training.
TINY = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}


@pytest.fixture
def tiny_overrides() -> dict:
    return dict(TINY)
