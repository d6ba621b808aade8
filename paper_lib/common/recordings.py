"""Simulated material a notebook draws (an episode, rendered frames), recorded once and committed.

A rebuild reads these files and never steps an env: MuJoCo's last float bits differ across CPUs and chaotic
episodes amplify them, so an episode or frame simulated at rebuild time would differ from machine to machine.
`make recollect` records them again; a notebook's `live` parameter plays them in place instead.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from paper_lib.common.io import save_npz_atomic

RECORD_AGAIN = "record it again with `make recollect`, or run the notebook with `-p live True` to play it in place"


def _plain(value: Any) -> Any:
    """`value` as JSON gives it back (tuples become lists), so settings compare equal to what a file holds."""
    return json.loads(json.dumps(value))


def save_recording(path: str | os.PathLike[str], settings: dict[str, Any], **arrays: np.ndarray) -> Path:
    """Write `arrays` with the `settings` that produced them (JSON, checked by `load_recording`) atomically."""
    return save_npz_atomic(path, settings=np.array(json.dumps(_plain(settings), sort_keys=True)), **arrays)


def load_recording(path: str | os.PathLike[str], expected: dict[str, Any]) -> tuple[dict[str, Any],
                                                                                    dict[str, np.ndarray]]:
    """(settings, arrays) of a recording made with the `expected` settings; a missing file or one recorded with
    other settings is one error naming the difference and how to record it again."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: nothing recorded yet; {RECORD_AGAIN}")
    with np.load(path, allow_pickle=False) as data:
        if "settings" not in data.files:
            raise ValueError(f"{path} is not a recording (it has no settings); {RECORD_AGAIN}")
        settings = json.loads(str(data["settings"]))
        arrays = {name: data[name] for name in data.files if name != "settings"}
    wrong = [f"{key} is {settings.get(key)!r}, wanted {value!r}" for key, value in _plain(expected).items()
             if settings.get(key) != value]
    if wrong:
        raise ValueError(f"{path} was recorded with other settings ({'; '.join(wrong)}); {RECORD_AGAIN}")
    return settings, arrays
