"""Atomic file writing, and the checks that keep a write from destroying what is at its destination.

Tables, figures and checkpoints are read by later pipeline stages; a run that
crashes mid-write must never leave a half-written file that looks finished.
Every writer here writes into a temporary folder beside the target (same file
system, so ``os.replace`` is atomic) and moves the result onto the target only
after the write succeeded.

Every temporary folder holds a marker file (`TEMP_MARKER`): a folder left by a
killed writer is deleted (or put back) only when it carries the marker, so a
user's own `.<name>.something` beside a target is never touched. A file writer
holds an advisory lock (flock) on its marker while it writes, which the kernel
drops when the process dies: the next write of the same file deletes the
temporary folders whose marker nobody holds (a killed writer's), never a live
writer's, so a killed rebuild leaves nothing behind once it is run again.

A kill can land at any instruction, so no folder is ever unmarked while it holds
anything: a new folder is empty until marked, a folder is emptied before its
marker goes (`_delete_temp`), and a folder swap moves an unmarked payload out of
and into a marked wrapper (`atomic_dir`). A killed writer therefore leaves a
marked folder or an empty one (`_holds_nothing`), and both are swept.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
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

#: The file inside every temporary folder this module makes: it proves the folder is ours to delete.
TEMP_MARKER = ".paper_lib_temp"
_MARKER_TEXT = "a temporary folder of paper_lib.common.io; deleted when its writer is done or was killed\n"


class DestinationError(ValueError):
    """A write destination that the write would destroy, or that cannot hold the output."""


# ----------------------------------------------------------------------------- temporary folders


def _mark(folder: Path) -> None:
    """Put the marker into `folder`: from now on `is_ours` may delete or restore it."""
    (folder / TEMP_MARKER).write_text(_MARKER_TEXT)


def _holds_nothing(entry: Path) -> bool:
    """Whether `entry` is a real folder holding nothing but, at most, a marker (whole or partly written).

    What a writer killed before its marker was written, or after `_delete_temp` removed it, leaves: deleting
    it loses nothing, marked or not.
    """
    if entry.is_symlink() or not entry.is_dir():
        return False
    try:
        names = os.listdir(entry)
        if not names:
            return True
        marker = entry / TEMP_MARKER
        if names != [TEMP_MARKER] or marker.is_symlink() or not marker.is_file():
            return False
        return _MARKER_TEXT.startswith(marker.read_text())
    except (OSError, UnicodeDecodeError):
        return False


def _delete_temp(folder: Path) -> None:
    """Delete a temporary folder, its marker last: a kill part-way leaves it marked, or empty (`_holds_nothing`).

    `shutil.rmtree` deletes in directory order, and a kill after it removed the marker left an unmarked folder
    that nothing would ever delete (a CI run's `..ckpt.resume.*.tmp`).
    """
    if folder.is_symlink() or not folder.is_dir():
        return
    for entry in os.listdir(folder):
        if entry != TEMP_MARKER:
            path = folder / entry
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
    (folder / TEMP_MARKER).unlink(missing_ok=True)
    try:
        os.rmdir(folder)
    except OSError:
        pass


def is_ours(entry: str | os.PathLike[str]) -> bool:
    """Whether `entry` is a temporary folder this module made (a real folder holding the marker with its text)."""
    entry = Path(entry)
    marker = entry / TEMP_MARKER
    if entry.is_symlink() or not entry.is_dir() or marker.is_symlink() or not marker.is_file():
        return False
    try:
        return marker.read_text() == _MARKER_TEXT
    except (OSError, UnicodeDecodeError):
        return False


def _temp_dir(parent: Path, name: str) -> Path:
    """A new marked temporary folder `.<name>.<random>.tmp` in `parent`."""
    tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{name}.", suffix=".tmp"))
    _mark(tmp)
    return tmp


def _held_temp_dir(parent: Path, name: str) -> tuple[Path, int]:
    """`_temp_dir` whose marker this process holds locked (flock) until `_release`: a live writer's temp.

    The marker is locked before its text is written, so a sweeper that finds the text finds the lock held.
    """
    while True:
        tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{name}.", suffix=".tmp"))
        try:
            fd = os.open(tmp / TEMP_MARKER, os.O_WRONLY | os.O_CREAT, 0o644)
        except FileNotFoundError:  # a sweeper removed the still empty folder: take another
            continue
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, _MARKER_TEXT.encode())
        try:
            if os.stat(tmp / TEMP_MARKER).st_ino == os.fstat(fd).st_ino:
                return tmp, fd
        except FileNotFoundError:
            pass
        os.close(fd)  # a sweeper deleted the folder before this process held its marker: take another


def _release(fd: int) -> None:
    os.close(fd)  # closing drops the flock


def remove_dead_temps(path: str | os.PathLike[str]) -> list[Path]:
    """Delete the marked temporary folders of file `path` whose writer is gone (their marker unlocked).

    Safe beside concurrent writers of the same file: a live writer holds its marker locked. Returns them.
    """
    target = Path(path)
    if not target.parent.is_dir():
        return []
    pattern = _temp_pattern(target.name)
    dead = []
    for entry in sorted(target.parent.iterdir()):
        if not pattern.fullmatch(entry.name):
            continue
        if not (entry / TEMP_MARKER).exists() and _holds_nothing(entry):
            try:
                os.rmdir(entry)  # fails if a live writer has just put its marker in: it stays
                dead.append(entry)
            except OSError:
                pass
        elif is_ours(entry) or _holds_nothing(entry):
            if _delete_if_writer_gone(entry):
                dead.append(entry)
    return dead


def _delete_if_writer_gone(folder: Path) -> bool:
    """Delete `folder` while holding its marker's lock, if no live process holds it; True if deleted.

    A writer that takes the lock after this (its marker created, not locked yet) finds its marker gone and starts
    over (`_held_temp_dir`).
    """
    try:
        fd = os.open(folder / TEMP_MARKER, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return False
    try:
        _delete_temp(folder)
    finally:
        os.close(fd)
    return True


def _temp_pattern(name: str) -> re.Pattern[str]:
    """The names `_temp_dir` and `_old_copy` give for `name` (mkdtemp's random part has no dot)."""
    return re.compile(rf"\.{re.escape(name)}\.(?:[A-Za-z0-9_]+\.tmp|old)")


# ----------------------------------------------------------------------------- door checks


def _nearest_existing(path: Path) -> Path:
    """`path` or its closest ancestor that exists (a link counts as existing, even a broken one)."""
    path = Path(os.path.abspath(path))
    while not os.path.lexists(path) and path != path.parent:
        path = path.parent
    return path


def check_folder_destination(path: str | os.PathLike[str], what: str = "output folder") -> Path:
    """Refuse a folder destination that cannot be written, before the work that would fill it.

    `path` may be missing (it is created on writing) or an existing folder; a file there, a path under a file,
    or a folder that cannot be written is one DestinationError naming it. Nothing is created here. An empty path
    is refused: Path("") is the current folder, which nobody means by an empty --out.
    """
    if not str(os.fspath(path)).strip():
        raise DestinationError(f"{what} is empty ({os.fspath(path)!r}), which would write into the current folder; "
                               "give a folder path (e.g. --out results/my_agent), or leave it out to write nothing")
    target = Path(path)
    if os.path.lexists(target) and not target.is_dir():
        kind = "a broken link" if target.is_symlink() else "a file"
        raise DestinationError(f"{what} {target} is {kind}, not a folder; give a folder path "
                               f"(the {kind.split()[-1]} was left as it is)")
    existing = _nearest_existing(target)
    if not existing.is_dir():
        raise DestinationError(f"{what} {target} lies under {existing}, which is a file, not a folder; "
                               "give a path under a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise DestinationError(f"{what} {target}: the folder {existing} is read-only; give a folder you can write "
                               f"or make it writable (chmod u+w {existing})")
    return target


def check_file_destination(path: str | os.PathLike[str], what: str = "output file") -> Path:
    """Refuse a file destination that is a folder, or where no file can be written (see check_folder_destination)."""
    target = Path(path)
    if target.is_dir():
        raise DestinationError(f"{what} {target} is a folder, not a file; give a file path "
                               "(the folder was left as it is)")
    check_folder_destination(target.parent, f"the folder of {what} {target}")
    return target


def check_replaceable_dir(path: str | os.PathLike[str], what: str = "folder") -> Path:
    """`atomic_dir` swaps folders: a file or a link at `path` would be moved aside and lost, so refuse it."""
    target = Path(path)
    if target.is_symlink():
        raise DestinationError(f"{what} {target} is a link; replacing it would replace the link, not the folder it "
                               "points to: give the real folder's path")
    if target.exists() and not target.is_dir():
        raise DestinationError(f"{what} {target} exists and is a file, not a folder; move the file away or give "
                               "another path (the file was left as it is)")
    return check_folder_destination(target, what)


# ----------------------------------------------------------------------------- files


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    The temporary file has ``path``'s name inside a marked temporary folder, so libraries that choose
    a format from the file extension (matplotlib, numpy) behave as for the real name. On any exception
    the temporary folder is deleted and the target is left untouched; a kill leaves it, and the next
    write of ``path`` deletes it (`remove_dead_temps`).
    """
    target = Path(path)
    if target.name == TEMP_MARKER:
        raise DestinationError(f"{target}: {TEMP_MARKER} is the name of paper_lib's temporary-folder marker; "
                               "give the file another name")
    check_file_destination(target, "file")
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_dead_temps(target)  # a killed earlier writer's temp (issue 71: `git status` clean after a rerun)
    stage, held = _held_temp_dir(target.parent, target.name)
    tmp = stage / target.name
    try:
        tmp.touch()  # an empty file, as mkstemp gave: writers may open it for update
        yield tmp
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, target)
    finally:
        _delete_temp(stage)
        _release(held)


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


_FILES_STAGE = "paper_lib_files"
#: Inside an `atomic_files` stage: the journal (the names being moved in, and which had an old file) and the old
#: files' copies. The journal exists only while the moves run: a stage holding it was stopped part-way.
_JOURNAL = ".paper_lib_journal.json"
_OLD = ".paper_lib_old"


class MixedFilesError(OSError):
    """A group of files could be neither moved in whole nor put back: `recover_files` finishes putting it back."""


@contextmanager
def atomic_files(folder: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary folder; move every file written there into ``folder`` only if the block succeeds.

    For a group of files that belong together (one run's outputs) in a folder that may hold other
    files: a failure part-way (a full disk, a crashing writer) moves none of them, so ``folder`` never
    holds one run's files beside another's. Existing files of other names are left alone.

    The moves are all or nothing: before the first, the old files of those names are linked aside and a
    journal is written; a move that fails puts every old file back (and removes the new ones that had
    none), and a kill part-way leaves the journal, so the next `atomic_files` or `recover_files` on
    ``folder`` puts the old group back before anything else.
    """
    target = check_folder_destination(folder)
    target.mkdir(parents=True, exist_ok=True)
    recover_files(target)
    stage = _temp_dir(target, _FILES_STAGE)
    journal = stage / _JOURNAL
    try:
        yield stage
        written = sorted(p for p in stage.iterdir() if p.name != TEMP_MARKER)
        for entry in written:  # every check before the first move: no move may fail half-way through the group
            if entry.name in (_JOURNAL, _OLD):
                raise DestinationError(f"{entry.name} is the name of atomic_files' journal; give the file another name")
            if not entry.is_file() or entry.is_symlink():
                raise DestinationError(f"atomic_files moves files only; {entry.name} is not a file")
            if (target / entry.name).is_dir():
                raise DestinationError(f"{target / entry.name} is a folder; the file {entry.name} cannot replace it: "
                                       "move the folder away (it was left as it is)")
        names = [entry.name for entry in written]
        had_old = _keep_old(target, stage, names)
        _write_journal(journal, names, had_old)
        try:
            for name in names:
                os.replace(stage / name, target / name)
        except BaseException as err:
            try:
                _put_back(target, stage)
            except OSError as again:
                raise MixedFilesError(f"moving the files into {target} failed part-way ({err}), and putting the old "
                                      f"ones back failed too ({again}); run paper_lib.common.io.recover_files("
                                      f"{str(target)!r}) to finish putting them back") from err
            raise
        journal.unlink()  # every new file is in: nothing left to put back
    finally:
        if not journal.exists():  # a journal left means the old files are still needed: recover_files uses them
            _delete_temp(stage)


def _keep_old(target: Path, stage: Path, names: list[str]) -> list[str]:
    """Link (or copy) the files the group replaces into the stage, untouched at `target`; return their names."""
    old = stage / _OLD
    old.mkdir()
    had_old = [name for name in names if os.path.lexists(target / name)]
    for name in had_old:
        try:
            os.link(target / name, old / name, follow_symlinks=False)
        except OSError:  # a file system without hard links
            shutil.copy2(target / name, old / name, follow_symlinks=False)
    return had_old


def _write_journal(journal: Path, names: list[str], had_old: list[str]) -> None:
    """Write the journal in one rename: a kill leaves it whole or absent."""
    part = journal.with_name(journal.name + ".part")
    part.write_text(json.dumps({"names": names, "had_old": had_old}, sort_keys=True))
    os.rename(part, journal)


def _put_back(target: Path, stage: Path) -> None:
    """Undo a group's moves from its journal: each old file back, each new file that had none removed. Repeatable."""
    journal = json.loads((stage / _JOURNAL).read_text())
    for name in journal["names"]:
        if name in journal["had_old"]:
            if os.path.lexists(stage / _OLD / name):
                os.replace(stage / _OLD / name, target / name)
        elif not os.path.lexists(stage / name) and os.path.lexists(target / name):
            os.unlink(target / name)  # moved in, and there was nothing before it
    (stage / _JOURNAL).unlink()


def recover_files(folder: str | os.PathLike[str]) -> list[Path]:
    """Put back the old files of an `atomic_files` group whose moves a kill stopped part-way, and delete its stage.

    Only stages that carry the marker are touched. Returns the stages it finished; called by every `atomic_files`
    on `folder` before it writes.
    """
    target = Path(folder)
    if not target.is_dir():
        return []
    pattern = _temp_pattern(_FILES_STAGE)
    stages = sorted(entry for entry in target.iterdir()
                    if pattern.fullmatch(entry.name) and (is_ours(entry) or _holds_nothing(entry)))
    for stage in stages:
        if (stage / _JOURNAL).is_file():
            _put_back(target, stage)
        _delete_temp(stage)
    return stages


# ----------------------------------------------------------------------------- folders


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

    Only needed where the file system cannot exchange two paths atomically (see `atomic_dir`), and only
    for an old copy `atomic_dir` marked: a `.<name>.old` of the user's is never moved.
    """
    target = Path(path)
    old = _old_copy(target)
    if not os.path.lexists(target) and is_ours(old):
        os.rename(old, target)
        (target / TEMP_MARKER).unlink(missing_ok=True)


def _remove_ours(parent: Path, name: str) -> list[Path]:
    """Delete the marked (or empty) temporary folders of `name` in `parent`; anything unmarked stays."""
    if not parent.is_dir():
        return []
    pattern = _temp_pattern(name)
    stale = sorted(entry for entry in parent.iterdir()
                   if pattern.fullmatch(entry.name) and (is_ours(entry) or _holds_nothing(entry)))
    for entry in stale:
        _delete_temp(entry)
    return stale


def remove_stale_temps(path: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporary folders (`.<name>.<random>.tmp`, `.<name>.old`) a killed writer of ``path`` left.

    Only folders that carry the marker are deleted: a resume point, a log folder or a user's file of a
    similar name is never touched. Call it before writing ``path`` again, from the one process that writes it.
    Returns the deleted folders.
    """
    target = Path(path)
    recover_dir(target)
    return _remove_ours(target.parent, target.name)


@contextmanager
def atomic_dir(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; swap it in for ``path`` only if the block succeeds.

    At every instant the complete old folder or the complete new one is at ``path``: the two
    are exchanged in one atomic rename (Linux), and the old one is deleted afterwards. Where
    the exchange is unsupported, the old folder is renamed to `.<name>.old` first and
    `recover_dir` puts it back if a kill lands between the two renames. A file or a link at
    ``path`` is refused (DestinationError) before anything is written: the swap would lose it.

    The yielded folder is `payload` inside a marked wrapper, so neither the new folder before the swap nor the
    old one after it is ever unmarked: a kill at any point leaves the target whole and a wrapper that the next
    write sweeps.
    """
    target = Path(path)
    check_replaceable_dir(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(target)
    wrapper = _temp_dir(target.parent, target.name)
    tmp = wrapper / "payload"
    tmp.mkdir(mode=0o777 & ~_UMASK)
    try:
        yield tmp
        check_replaceable_dir(target)  # nothing else may have appeared there while the block ran
        if not os.path.lexists(target):
            os.rename(tmp, target)
        elif not _exchange(tmp, target):  # exchanged: the old folder is the payload now, inside the marked wrapper
            _swap_by_renames(tmp, target)
    finally:
        _delete_temp(wrapper)


def _swap_by_renames(tmp: Path, target: Path) -> None:
    """The swap without an atomic exchange: old folder aside (marked for `recover_dir`), new in, old deleted."""
    old = _old_copy(target)
    if os.path.lexists(old):
        raise DestinationError(f"{old} is in the way of replacing {target} and is not a temporary folder of ours; "
                               "move it away (it was left as it is)")
    _mark(target)
    try:
        os.rename(target, old)
    except OSError:
        (target / TEMP_MARKER).unlink(missing_ok=True)
        raise
    os.rename(tmp, target)
    _delete_temp(old)
