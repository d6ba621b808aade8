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


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one atomic step (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    result = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange)
    return result == 0


def _old_copy(target: Path) -> Path:
    return target.with_name(f".{target.name}.old")


def recover_dir(path: str | os.PathLike[str]) -> None:
    """Undo a swap that a kill interrupted: put the complete old folder back if the target is missing.

    Only needed where the file system cannot exchange two paths atomically (see `atomic_dir`).
    """
    target = Path(path)
    old = _old_copy(target)
    if not target.exists() and old.is_dir():
        os.rename(old, target)


def remove_stale_temps(path: str | os.PathLike[str]) -> list[Path]:
    """Delete temporary siblings (`.<name>.*`) that a killed writer of ``path`` left behind.

    Call it before writing ``path`` again, from the one process that writes it.
    """
    import shutil

    target = Path(path)
    recover_dir(target)
    stale = sorted(target.parent.glob(f".{target.name}.*")) if target.parent.is_dir() else []
    for entry in stale:
        if entry.name.endswith((".resume", ".tensorboard")):  # resume points and logs are not temporary
            continue
        shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)
    return stale


@contextmanager
def atomic_dir(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; swap it in for ``path`` only if the block succeeds.

    At every instant the complete old folder or the complete new one is at ``path``: the two
    are exchanged in one atomic rename (Linux), and the old one is deleted afterwards. Where
    the exchange is unsupported, the old folder is renamed to `.<name>.old` first and
    `recover_dir` puts it back if a kill lands between the two renames.
    """
    import shutil

    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(target)
    tmp = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp"))
    os.chmod(tmp, 0o777 & ~_UMASK)
    try:
        yield tmp
        if not target.exists():
            os.rename(tmp, target)
        elif _exchange(tmp, target):
            shutil.rmtree(tmp)  # now holds the old folder
        else:
            old = _old_copy(target)
            os.rename(target, old)
            os.rename(tmp, target)
            shutil.rmtree(old)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
