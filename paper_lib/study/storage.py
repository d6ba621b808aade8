"""Optuna storages for the study: the local SQLite file by default, any database URL to spread workers.

Why a database (Optuna's RDBStorage) and not a journal file: in Optuna 5.0 only RDBStorage
records heartbeats, and the heartbeat is what lets a worker that was killed mid-trial lose
only that trial: once its heartbeat is `grace_period` seconds old, the next worker to look
marks it FAIL and `RetryHeartbeatStaleTrialCallback` queues a copy with the same settings.

    sqlite:///results/cpu/studies/studies.db     the default: one file per profile, resumes after a kill
    postgresql://user:password@host:5432/db       one study over many machines, each running the same worker

A local PostgreSQL server for a machine without one (the `pgserver` package ships the binaries):

    python -m paper_lib.study.storage postgres results/cpu/studies/pgdata     # prints the URL, serves until Ctrl-C
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlsplit

import optuna
import sqlalchemy.exc
from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback

from paper_lib.study.config import Heartbeat

#: URL schemes of the databases Optuna's RDBStorage is tested with (SQLAlchemy may add `+driver`).
SCHEMES = ("sqlite", "postgresql", "mysql")
#: Two workers that start at once on a fresh database both try to create its tables; the loser retries.
OPEN_TRIES = 5
#: The first bytes of every SQLite database file (an empty file is a new database too).
SQLITE_HEADER = b"SQLite format 3\x00"


@contextmanager
def experimental_ok() -> Iterator[None]:
    """Heartbeats, their retry callback and metric names are Optuna features marked experimental; we use them knowingly."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        yield


def check_url(url: str) -> str:
    """A database URL Optuna can keep heartbeats in, or one ValueError saying what to give instead."""
    if not isinstance(url, str) or not url:
        raise ValueError(f"storage URL {url!r}: give a database URL, e.g. sqlite:///results/cpu/studies/studies.db")
    scheme = urlsplit(url).scheme.split("+")[0]
    if scheme not in SCHEMES:
        hint = (" Optuna's journal files keep no heartbeats (Optuna 5.0), so a killed worker's trial could not be "
                "failed and retried;" if url.endswith((".log", ".journal")) or "journal" in url else "")
        raise ValueError(f"storage {url!r} is not a database URL.{hint} give sqlite:///<path>.db (local) or "
                         "postgresql://user:password@host/db (many machines)")
    if scheme == "sqlite":
        path = url.split(":///", 1)[1] if ":///" in url else ""
        if not path or path == ":memory:":
            raise ValueError(f"storage {url!r}: an in-memory database is lost when the worker ends; "
                             "give a file, e.g. sqlite:///results/cpu/studies/studies.db")
        check_sqlite_file(Path(path))
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    return url


def check_sqlite_file(path: Path) -> None:
    """An existing file must be an SQLite database: anything else fails deep in SQLAlchemy, naming no file."""
    if path.is_dir():
        raise ValueError(f"study storage {path} is a folder, not an SQLite file; give a .db file path, e.g. "
                         "sqlite:///results/cpu/studies/studies.db")
    if not path.is_file():
        return
    try:
        with open(path, "rb") as f:
            head = f.read(len(SQLITE_HEADER))
    except OSError as err:
        raise ValueError(f"study storage {path} cannot be read, got {type(err).__name__}: {err}; fix its "
                         "permissions or give another .db file") from None
    if head and head != SQLITE_HEADER:
        raise ValueError(f"study storage {path} is not an SQLite database, got a file starting with {head[:16]!r}; "
                         "move it aside (it was left as it is) or give another .db file")


def open_storage(url: str, heartbeat: Heartbeat) -> RDBStorage:
    """RDBStorage with heartbeats: a trial whose worker died is failed and queued again (up to max_retry times)."""
    check_url(url)
    engine_kwargs = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else {"pool_pre_ping": True}
    last: Exception | None = None
    for attempt in range(OPEN_TRIES):
        try:
            with experimental_ok():
                return RDBStorage(url, engine_kwargs=engine_kwargs, heartbeat_interval=heartbeat.interval,
                                  grace_period=heartbeat.grace_period,
                                  heartbeat_stale_trial_callback=RetryHeartbeatStaleTrialCallback(
                                      max_retry=heartbeat.max_retry))
        except (sqlalchemy.exc.OperationalError, sqlalchemy.exc.IntegrityError,
                sqlalchemy.exc.ProgrammingError) as err:
            last = err  # e.g. "table already exists" from a worker that started at the same moment
            time.sleep(0.5 * (attempt + 1))
        except sqlalchemy.exc.DatabaseError as err:  # e.g. a damaged file: trying again changes nothing
            raise ValueError(f"the study storage {url!r} is not a usable database, got {type(err).__name__}: "
                             f"{str(err).splitlines()[0]}; move the file aside or give another storage URL") from err
    raise ValueError(f"cannot open the study storage {url!r} ({type(last).__name__}: "
                     f"{str(last).splitlines()[0] if last else ''}); check that the database is reachable") from last


def local_postgres(data_dir: str | Path, cleanup: str = "stop") -> tuple[object, str]:
    """Start (or reuse) a PostgreSQL server on `data_dir` with `pgserver`; returns (server, URL).

    The server listens on a Unix socket in `data_dir` only; it stops when the last process
    that asked for it exits (`cleanup="delete"` also removes `data_dir`).
    """
    try:
        with warnings.catch_warnings():  # platformdirs warns when XDG_RUNTIME_DIR is unset; pgserver falls back to /tmp
            warnings.filterwarnings("ignore", message=".*XDG_RUNTIME_DIR")
            import pgserver
    except ImportError as err:
        raise ValueError("pgserver is not installed; run `make setup` (it is pinned in environment.lock)") from err
    data_dir = Path(data_dir).resolve()
    data_dir.mkdir(parents=True, exist_ok=True)
    try:
        server = pgserver.get_server(data_dir, cleanup_mode=cleanup)
    except Exception as err:  # pgserver raises plain exceptions from pg_ctl/initdb; name the log
        said = (getattr(err, "stderr", None) or getattr(err, "output", None) or b"")
        said = said.decode(errors="replace") if isinstance(said, bytes) else str(said)
        raise RuntimeError(f"PostgreSQL did not start in {data_dir} ({type(err).__name__}: {err}; it said: "
                           f"{said.strip()[-800:]!r}); see {data_dir / 'log'}. As root, pgserver runs the server as "
                           "user `pgserver`, which must be able to enter every parent folder of the data folder") from err
    return server, server.get_uri()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Study storages.")
    sub = parser.add_subparsers(dest="command", required=True)
    pg = sub.add_parser("postgres", help="start a local PostgreSQL server (pgserver), print its URL, serve until Ctrl-C")
    pg.add_argument("data_dir")
    args = parser.parse_args(argv)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        server, url = local_postgres(args.data_dir)
    except (ValueError, RuntimeError) as err:
        parser.exit(2, f"error: {err}\n")
    print(url, flush=True)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # exit normally, so pgserver stops the server
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        del server


if __name__ == "__main__":
    main()
