"""Re-use one run's guard experiment while nothing it depends on has changed.

The `guard` stage depends on the whole checkpoints folder, so every run that lands makes it stale,
and replaying every run's episodes (20-60 s each here) would make each `make reproduce` slower as the
matrix grows. ``cached_experiment`` keeps each run's tables next to its saved guards, keyed by a
fingerprint of everything the experiment reads: the checkpoint's files, the settings, the action
mode, the seed, the source of `paper_lib` and the package versions (pandas too: it reads the tables back). Any change to one of them
replays the run; otherwise its tables are read back exactly (pickle keeps dtypes and every bit).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import json
from pathlib import Path

import pandas as pd

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.common.io import atomic_path
from paper_lib.common.provenance import package_versions
from paper_lib.guard.experiment import GuardRun, run_experiment
from paper_lib.guard.settings import GuardSettings
from paper_lib.ood.collect import ActionMode

TABLES = ("episodes", "returns", "traces")
FOLDER = "experiment"
#: Every paper_lib module a guard experiment runs (`tests/guard/test_guard.py` checks a real run imports no other).
SOURCE_MODULES = tuple(f"paper_lib{suffix}" for suffix in (
    "", ".common", ".common.checks", ".common.io", ".common.provenance", ".methods", ".methods.buffer",
    ".methods.derived", ".methods.groups", ".methods.independent", ".methods.inference", ".methods.layers",
    ".methods.networks", ".methods.per_state", ".methods.policy", ".methods.trpo", ".measures", ".measures.definitions",
    ".measures.detectors", ".measures.estimates", ".agents", ".agents.checkpoints", ".agents.envs", ".agents.factory",
    ".ood", ".ood.atari", ".ood.collect", ".ood.datasets", ".ood.frame_store", ".ood.mujoco", ".ood.pixels",
    ".pipeline", ".pipeline.config", ".pipeline.layout", ".guard", ".guard.cache", ".guard.conformal", ".guard.core",
    ".guard.experiment", ".guard.scores", ".guard.sequential", ".guard.settings", ".guard.shift", ".guard.wrappers"))


def fingerprint(checkpoint: Checkpoint, settings: GuardSettings, action_mode: ActionMode, seed: int) -> str:
    """A hash of every input of ``run_experiment`` for this run (code and package versions included)."""
    digest = hashlib.sha256()
    for path in sorted(p for p in Path(checkpoint.folder).iterdir() if p.is_file()):
        digest.update(path.name.encode() + path.read_bytes())
    for name in SOURCE_MODULES:
        digest.update(name.encode() + Path(importlib.util.find_spec(name).origin).read_bytes())
    described = {"settings": dataclasses.asdict(settings), "action_mode": action_mode.to_dict(), "seed": seed,
                 "versions": {**package_versions(), "pandas": pd.__version__}}
    digest.update(json.dumps(described, sort_keys=True, default=str).encode())
    return digest.hexdigest()


def cached_experiment(checkpoint: Checkpoint, settings: GuardSettings, action_mode: ActionMode, seed: int,
                      guards_dir: str | Path) -> tuple[GuardRun, bool]:
    """(the run's experiment, whether it came from the cache): replayed only if its fingerprint changed.

    A run read back has an empty ``guards`` dict; its guards are the ones saved in ``guards_dir``.
    """
    folder = Path(guards_dir) / FOLDER
    key = fingerprint(checkpoint, settings, action_mode, seed)
    meta = folder / "fingerprint.json"
    if meta.is_file() and json.loads(meta.read_text()).get("fingerprint") == key:
        tables = {name: pd.read_pickle(folder / f"{name}.pkl") for name in TABLES}
        return GuardRun(**tables, guards={}, n_redrawn=json.loads(meta.read_text())["n_redrawn"]), True
    run = run_experiment(checkpoint, settings, action_mode, seed, guards_dir=guards_dir)
    folder.mkdir(parents=True, exist_ok=True)
    for name in TABLES:
        with atomic_path(folder / f"{name}.pkl") as tmp:
            getattr(run, name).to_pickle(tmp)
    with atomic_path(meta) as tmp:  # written last: a killed write leaves no matching fingerprint
        Path(tmp).write_text(json.dumps({"fingerprint": key, "n_redrawn": run.n_redrawn}, indent=1) + "\n")
    return run, False
