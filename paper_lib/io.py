"""Atomic file writing.

Tables, figures and checkpoints are read by later pipeline stages; a run that
crashes mid-write must never leave a half-written file that looks finished.
Every writer here writes to a temporary file in the target's folder (same file
system, so ``os.replace`` is atomic) and renames it onto the target only after
the write succeeded.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

# mkstemp creates files readable by the owner only; finished files get the usual
# permissions (0o666 minus the umask), as open() would give them.
_UMASK = os.umask(0)
os.umask(_UMASK)
_FILE_MODE = 0o666 & ~_UMASK


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    The temporary name keeps ``path``'s suffix, so libraries that choose a format
    from the file extension (matplotlib, numpy) behave as for the real name.
    On any exception the temporary file is deleted and the target is left untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=f".tmp{target.suffix}")
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8, ``\\n`` line ends on every OS) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
    return Path(path)


def save_npz_atomic(path: str | os.PathLike[str], **arrays: Any) -> Path:
    """Save ``arrays`` with ``np.savez_compressed`` to ``path`` atomically.

    ``path`` must end in ``.npz``: numpy would otherwise append the suffix itself and
    the file would land beside the name the caller asked for.
    """
    target = Path(path)
    if target.suffix != ".npz":
        raise ValueError(f"save_npz_atomic: path {target} must end in '.npz' (numpy appends it otherwise); rename it.")
    with atomic_path(target) as tmp:
        with open(tmp, "wb") as f:  # a file object stops numpy from touching the name
            np.savez_compressed(f, **arrays)
    return target


def write_json_atomic(path: str | os.PathLike[str], obj: Any, indent: int = 2) -> Path:
    """Write ``obj`` as JSON (sorted keys, so equal inputs give equal bytes) atomically."""
    text = json.dumps(obj, indent=indent, sort_keys=True) + "\n"
    return write_text_atomic(path, text)
