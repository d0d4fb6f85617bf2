"""Optuna storages for many workers: URLs, heartbeats, and one-line storage errors.

Accepted storage URLs:

- ``postgresql://user@host:port/db`` (also ``postgres://``; run with psycopg 3,
  i.e. ``postgresql+psycopg://``) — many machines;
- ``journal:///path/to/study.log`` or a plain path ending in ``.log`` — Optuna's
  journal file (``JournalFileBackend``), one machine or a shared NFS folder; its
  writers take a kernel lock that dies with its holder before Optuna's symlink lock
  (:mod:`surrogate.storage._lock`);
- ``sqlite:///path.db`` — one worker only: SQLite hands the same enqueued trial
  to two workers (a race in ``study.ask``), so more than one is refused;
- any other SQLAlchemy URL Optuna's ``RDBStorage`` accepts (``mysql+pymysql://``).

Workers keep a heartbeat on their running trial; a trial whose heartbeat is
older than the grace period is failed by the next worker that looks, and
:class:`optuna.storages.RetryHeartbeatStaleTrialCallback` queues a copy of it
(``WAITING``) that another worker runs. ``RDBStorage`` has this built in; the
journal gets the same through :class:`_HeartbeatJournalStorage`, whose heartbeat
is a trial system attribute (clocks of the machines sharing it must agree to
within the grace period).
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import logging
import os
import time
import weakref
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import optuna
from optuna.storages import (
    JournalStorage,
    RDBStorage,
    RetryHeartbeatStaleTrialCallback,
)
from optuna.storages._heartbeat import BaseHeartbeat
from optuna.storages._rdb import models as _rdb_models
from optuna.storages.journal import JournalFileBackend
from optuna.trial import FrozenTrial, TrialState

from .._errors import InputDataError
from .._pool import check_jobs
from ._lock import JournalLock

__all__ = [
    "STORAGE_PATIENCE_S",
    "Patience",
    "StorageError",
    "check_heartbeat",
    "check_storage_patience",
    "check_storage_url",
    "check_workers",
    "in_memory_storage",
    "local_storage_file",
    "normalise_storage_url",
    "open_storage",
    "redacted_url",
    "refuse_in_memory",
    "retry_callback",
    "storage_error_message",
    "storage_kind",
    "unreachable",
    "unstored",
]

HEARTBEAT_ATTR = "surrogate:heartbeat"
MAX_RETRY = 3  # a trial whose worker dies three times in a row is left FAIL


_ENGINES: weakref.WeakSet[Any] = weakref.WeakSet()  # every database engine that connected


def _track_engines() -> None:
    """Remember each SQLAlchemy engine once it connects (Optuna's RDB storages)."""
    from sqlalchemy import event
    from sqlalchemy.engine import Engine

    if not event.contains(Engine, "engine_connect", _remember_engine):
        event.listen(Engine, "engine_connect", _remember_engine)


def _remember_engine(connection: Any) -> None:
    _ENGINES.add(connection.engine)


def _forget_inherited_connections() -> None:
    """In a forked child: let go of the parent's pooled database connections without
    closing them, so the child never ends a connection the parent still uses
    (SQLAlchemy, "Using Connection Pools with Multiprocessing or os.fork()"). A child
    that needs a storage opens its own."""
    for engine in list(_ENGINES):
        with contextlib.suppress(Exception):  # one broken engine must not keep the others
            engine.dispose(close=False)


_track_engines()
if hasattr(os, "register_at_fork"):  # POSIX; elsewhere no process is forked
    os.register_at_fork(after_in_child=_forget_inherited_connections)


class StorageError(InputDataError):
    """The storage cannot be opened or written (unreachable, read-only, full)."""


def normalise_storage_url(url: str) -> str:
    """The URL Optuna/SQLAlchemy understands; refuse what none of the forms match.

    ``postgres://`` and ``postgresql://`` get the psycopg 3 driver; a ``.log``
    path becomes ``journal:///<absolute path>``.
    """
    if not isinstance(url, str) or not url.strip():
        raise InputDataError(f"--storage must be a storage URL, got {url!r}")
    url = url.strip()
    for prefix in ("postgres://", "postgresql://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url.removeprefix(prefix)
    if url.startswith("journal:"):
        path = url.removeprefix("journal:").removeprefix("//")
        if not path or path.endswith("/"):
            raise InputDataError(
                f"--storage {url!r}: a journal URL names a file, e.g. journal:///srv/study.log"
            )
        return f"journal://{Path(path).resolve()}"
    if "://" not in url:
        if url.endswith(".log"):
            return f"journal://{Path(url).resolve()}"
        raise InputDataError(
            f"--storage {url!r} is not a storage URL; use postgresql://user@host/db, "
            "journal:///path/study.log (or a .log path) or sqlite:///path.db"
        )
    scheme = url.split("://", 1)[0]
    if scheme.split("+", 1)[0] not in ("sqlite", "postgresql", "mysql", "mariadb", "oracle"):
        raise InputDataError(
            f"--storage {url!r}: unknown scheme {scheme!r}; use postgresql://, "
            "journal:///path.log or sqlite:///path.db"
        )
    return url


def storage_kind(url: str) -> str:
    """``sqlite``, ``postgresql``, ``journal`` or ``rdb`` (another SQL database)."""
    url = normalise_storage_url(url)
    for kind in ("sqlite", "postgresql", "journal"):
        if url.startswith(kind):
            return kind
    return "rdb"


def in_memory_storage(url: str) -> bool:
    """Whether ``url`` is an SQLite database in this process's memory (``sqlite://``,
    ``sqlite:///:memory:``; with ``uri=true``, ``file::memory:`` or ``mode=memory``): it
    starts empty in every process and ends with it."""
    sqlite = _sqlite_database(url)
    return sqlite is not None and sqlite[1]


def _sqlite_database(url: str) -> tuple[str, bool] | None:
    """An SQLite URL's database file (as SQLite reads it) and whether it is in memory;
    None for another storage."""
    url = normalise_storage_url(url)
    if not url.startswith("sqlite"):
        return None
    from sqlalchemy.engine import make_url

    parsed = make_url(url)
    database = parsed.database or ""
    if str(parsed.query.get("uri", "")).lower() == "true":  # an SQLite URI filename
        file = database.removeprefix("file:")
        return file, parsed.query.get("mode") == "memory" or file.startswith(":memory:")
    return database, database in ("", ":memory:")


def refuse_in_memory(url: str, reader: str) -> None:
    """Refuse an in-memory database to ``reader``, which reads what another command or
    process stored: it would find nothing (one line, with the fix)."""
    if in_memory_storage(url):
        raise InputDataError(
            f"--storage {url!r}: an in-memory SQLite database starts empty in every process, "
            f"so {reader} would find nothing in it; use the file or server the study is "
            "stored in (journal:///path/study.log, sqlite:///path.db or postgresql://…)"
        )


def check_workers(url: str, workers: int) -> None:
    """Refuse more than one worker on SQLite, and workers in other processes on an
    in-memory database (one line, with the fix)."""
    check_jobs(workers, minimum=0)
    if workers != 1 and in_memory_storage(url):
        who = "the workers --jobs 0 plans for" if workers == 0 else f"--jobs {workers} workers"
        raise InputDataError(
            f"--storage {url!r}: an in-memory SQLite database exists only inside this process, "
            f"so {who} would never see it; use --storage journal:///path/study.log (one "
            "machine) or postgresql://user@host/db (many machines), or --jobs 1"
        )
    if workers > 1 and storage_kind(url) == "sqlite":
        raise InputDataError(
            f"--jobs {workers} on SQLite: SQLite hands the same queued trial to two workers; "
            "use --storage journal:///path/study.log (one machine) or "
            "--storage postgresql://user@host/db (many machines), or --jobs 1"
        )


def journal_path(url: str) -> Path | None:
    """The journal file of a journal URL, else None."""
    url = normalise_storage_url(url)
    return Path(url.removeprefix("journal://")) if url.startswith("journal://") else None


def local_storage_file(url: str) -> Path | None:
    """The SQLite or journal file of ``url``; None for a server or an in-memory database."""
    sqlite = _sqlite_database(url)
    if sqlite is not None:
        database, memory = sqlite
        return None if memory else Path(database)
    return journal_path(url)


def missing_local_storage(url: str) -> Path | None:
    """The SQLite or journal file of ``url`` if it does not exist yet, else None."""
    local = local_storage_file(url)
    return local if local is not None and not local.exists() else None


def unstored(url: str, reader: str) -> Path | None:
    """What ``reader`` — a command or worker that reads what another one stored — would
    find missing at ``url``: an in-memory database is refused (it starts empty in every
    process); else the SQLite or journal file if it does not exist yet (its caller
    refuses that with its own fix, creating nothing), else None."""
    refuse_in_memory(url, reader)
    return missing_local_storage(url)


def check_storage_url(url: str) -> str:
    """``url`` normalised, refused (InputDataError) where it cannot name a storage: an
    unknown scheme, or a SQLite or journal file in a folder that does not exist or that
    is itself a folder. Cheap and creates nothing: a command checks it before its work,
    not after."""
    normalised = normalise_storage_url(url)
    local = local_storage_file(normalised)
    if local is not None and not local.parent.is_dir():
        raise InputDataError(
            f"storage {url}: folder {local.parent} does not exist; create it first"
        )
    if local is not None and local.is_dir():
        raise InputDataError(f"storage {url}: {local} is a folder; name the file to use")
    return normalised


def open_storage(url: str, *, heartbeat_s: int | None = None, must_exist: bool = False) -> Any:
    """An Optuna storage for ``url`` with heartbeats every ``heartbeat_s`` seconds.

    Parameters
    ----------
    url : str
        A storage URL (module docstring).
    heartbeat_s : int, optional
        Heartbeat interval [s]; the grace period is three intervals. None: no
        heartbeat (a planner that runs nothing itself).
    must_exist : bool
        Refuse a SQLite or journal file that does not exist yet instead of
        creating it (a worker joins an existing plan).
    """
    url = check_storage_url(url)
    if heartbeat_s is not None:
        check_heartbeat(heartbeat_s)
    grace = None if heartbeat_s is None else 3 * heartbeat_s
    retry = retry_callback()
    path = journal_path(url)
    if must_exist:
        local = unstored(url, "a worker")
        if local is not None:
            raise InputDataError(
                f"no storage at {local} yet; plan the study first "
                "(surrogate run STUDY --storage URL --jobs 0)"
            )
    with storage_errors(url):
        if path is not None:
            return _HeartbeatJournalStorage(
                JournalFileBackend(str(path), lock_obj=JournalLock(str(path))),
                heartbeat_s=heartbeat_s,
                grace_s=grace,
                callback=retry,
            )
        with _quiet_experimental():
            return _HeartbeatRDBStorage(
                url,
                heartbeat_interval=heartbeat_s,
                grace_period=grace,
                heartbeat_stale_trial_callback=retry if heartbeat_s else None,
                engine_kwargs=_engine_kwargs(url),
            )


def check_heartbeat(heartbeat_s: Any) -> int:
    """``--heartbeat`` as given, or a one-line error."""
    if isinstance(heartbeat_s, bool) or not isinstance(heartbeat_s, int) or heartbeat_s < 1:
        raise InputDataError(
            f"--heartbeat must be a whole number of seconds ≥ 1, got {heartbeat_s!r}"
        )
    return heartbeat_s


def retry_callback() -> RetryHeartbeatStaleTrialCallback:
    """What queues the copy of a trial failed as stale (or interrupted): a ``WAITING``
    copy naming it in ``retry_history``, at most ``MAX_RETRY`` times for one run."""
    with _quiet_experimental():
        return RetryHeartbeatStaleTrialCallback(max_retry=MAX_RETRY)


def _engine_kwargs(url: str) -> dict[str, Any]:
    if url.startswith("postgresql"):
        return {"pool_pre_ping": True, "connect_args": {"connect_timeout": 10}}
    return {}


@contextlib.contextmanager
def _quiet_experimental() -> Iterator[None]:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        yield


class _HeartbeatJournalStorage(JournalStorage, BaseHeartbeat):
    """A journal storage with Optuna's heartbeat protocol.

    The heartbeat is the system attribute ``surrogate:heartbeat`` (UNIX time);
    a RUNNING trial is stale when both it and the trial's start are older than
    the grace period, so :func:`optuna.storages.fail_stale_trials` works as on
    an ``RDBStorage``.
    """

    def __init__(
        self,
        backend: JournalFileBackend,
        *,
        heartbeat_s: int | None,
        grace_s: int | None,
        callback: Callable[[optuna.Study, FrozenTrial], None] | None,
    ) -> None:
        super().__init__(backend)
        self._heartbeat_s = heartbeat_s
        self._grace_s = grace_s
        self._callback = callback

    def record_heartbeat(self, trial_id: int) -> None:
        self.set_trial_system_attr(trial_id, HEARTBEAT_ATTR, time.time())

    def _get_stale_trial_ids(self, study_id: int) -> list[int]:
        if self._grace_s is None:
            return []
        now = time.time()
        stale = []
        for trial in self.get_all_trials(study_id, deepcopy=False, states=(TrialState.RUNNING,)):
            start = trial.datetime_start.timestamp() if trial.datetime_start else 0.0
            last = max(start, float(trial.system_attrs.get(HEARTBEAT_ATTR, 0.0)))
            if now - last > self._grace_s:
                stale.append(trial._trial_id)
        return stale

    def get_heartbeat_interval(self) -> int | None:
        return self._heartbeat_s

    def get_heartbeat_stale_trial_callback(
        self,
    ) -> Callable[[optuna.Study, FrozenTrial], None] | None:
        return self._callback


class _HeartbeatRDBStorage(RDBStorage):
    """Optuna's RDB storage, whose stale check also fails a RUNNING trial that never
    got a heartbeat once its start is older than the grace period.

    A worker claims a trial (WAITING → RUNNING) and records its first heartbeat in two
    transactions; killed between them, or losing its connection for the first beat,
    it left a RUNNING trial that ``RDBStorage`` never judged stale (it skips trials
    without heartbeats), so the plan waited forever. The journal storage judges such a
    trial by its start already (:class:`_HeartbeatJournalStorage`). Machines sharing
    the storage must agree on the time to within the grace period.
    """

    def _get_stale_trial_ids(self, study_id: int) -> list[int]:
        stale = super()._get_stale_trial_ids(study_id)
        if self.heartbeat_interval is None:
            return stale
        grace = self.grace_period or 2 * self.heartbeat_interval
        now = datetime.datetime.now()  # the clock datetime_start was written with
        session = self.scoped_session()
        try:
            never_beat = (
                session.query(_rdb_models.TrialModel)
                .filter(_rdb_models.TrialModel.study_id == study_id)
                .filter(_rdb_models.TrialModel.state == TrialState.RUNNING)
                .filter(~_rdb_models.TrialModel.heartbeats.any())
                .all()
            )
            stale += [
                int(trial.trial_id)
                for trial in never_beat
                if trial.datetime_start is not None
                and (now - trial.datetime_start).total_seconds() > grace
            ]
        finally:
            session.close()
        return stale


def storage_error_message(error: BaseException, url: str | None = None) -> str | None:
    """One line for a storage failure (unreachable, read-only, full), else None."""
    import sqlalchemy.exc

    where = f" ({redacted_url(url)})" if url else ""
    if isinstance(error, optuna.exceptions.StorageInternalError) and error.__cause__:
        error = error.__cause__  # Optuna wraps the database's own error
    if isinstance(error, sqlalchemy.exc.SQLAlchemyError):
        detail = str(getattr(error, "orig", None) or error).strip().splitlines()
        text = detail[0] if detail else type(error).__name__
        low = text.lower()
        if "readonly" in low or "read-only" in low or "read only" in low:
            return f"the storage{where} is read-only ({text}); use a writable storage"
        if "full" in low or "no space" in low:
            return f"the storage{where} is full ({text}); free space or use another storage"
        return f"cannot use the storage{where}: {text}; check the URL and that the server runs"
    if isinstance(error, OSError):
        reason = error.strerror or str(error)
        name = f": {error.filename}" if error.filename else ""
        if error.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            return f"the storage{where} is full ({reason}); free space or use another storage"
        return f"cannot write the storage{where}: {reason}{name}; check the path and permissions"
    if isinstance(error, ImportError):
        return f"the storage driver is missing ({error.name}); pip install 'psycopg[binary]'"
    return None


def redacted_url(url: str) -> str:
    """The URL without a password (what a message or a report may show)."""
    head, sep, tail = url.partition("://")
    if sep and "@" in tail:
        credentials, _, host = tail.rpartition("@")
        user = credentials.split(":", 1)[0]
        return f"{head}://{user}@{host}"
    return url


@contextlib.contextmanager
def storage_errors(url: str | None = None) -> Iterator[None]:
    """Turn storage failures inside the block into :class:`StorageError`."""
    try:
        yield
    except (InputDataError, optuna.exceptions.UpdateFinishedTrialError):
        raise
    except Exception as error:
        message = storage_error_message(error, url)
        if message is None:
            raise
        raise StorageError(message) from error


def stale_trial_check(study: optuna.Study) -> None:
    """Fail stale trials (their copies are queued again by the retry callback)."""
    with _quiet_experimental():
        optuna.storages.fail_stale_trials(study)


# -- a storage that cannot be reached for a while --------------------------------------------
STORAGE_PATIENCE_S = 300.0
"""How long [s] a worker, or a planner waiting for workers, rides out a storage it reached
before and cannot reach now (a database restart, a failover) before it stops."""

_RETRY_S = (1.0, 10.0)  # first and longest wait between tries (at most a third of the grace)
_T = TypeVar("_T")
logger = logging.getLogger(__name__)


def unreachable(error: BaseException) -> bool:
    """Whether ``error`` says the database could not be reached — refused, dropped or shut
    down, which a restart or a failover ends — rather than that it refused the operation
    (read-only, full, no such database): a psycopg ``OperationalError`` without a SQLSTATE
    (the connection's own failure) or of class 08 (connection exception) or 57P (operator
    intervention), found anywhere in the error's chain of causes."""
    try:
        from psycopg import OperationalError
    except ImportError:
        return False
    seen: set[int] = set()
    cause: BaseException | None = error
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, OperationalError):
            state = cause.sqlstate
            return state is None or state.startswith(("08", "57P"))
        cause = cause.__cause__ or getattr(cause, "orig", None) or cause.__context__
    return False


def check_storage_patience(patience_s: Any) -> float:
    """``--storage-patience`` as a float, or a one-line error."""
    if isinstance(patience_s, bool) or not isinstance(patience_s, int | float):
        raise InputDataError(f"--storage-patience must be a number of seconds, got {patience_s!r}")
    if not patience_s >= 0:
        raise InputDataError(f"--storage-patience must be ≥ 0 s, got {patience_s!r}")
    return float(patience_s)


class Patience:
    """Rides out a storage that cannot be reached for up to ``patience_s``.

    ``patience(step)`` calls ``step`` and, while it fails because the storage cannot be
    reached (:func:`unreachable`), calls it again with growing waits; after
    ``patience_s`` of failures (or once ``stopping()``), the failure is raised as a
    :class:`StorageError` that says how long the storage was unreachable. Any other
    error is raised at once. A step is retried whole, so it must be safe to repeat
    (reads, and writes that say so when they were done already).

    A process that could not reach the storage within the last ``grace_s`` does not
    judge other workers' trials stale (:meth:`stale_check`): their heartbeats could not
    be written either, and a live trial failed as stale is run twice. The waits between
    tries are at most a third of the grace, so every worker is back (and has beaten or
    told) within a third of the grace after the storage is.
    """

    def __init__(
        self,
        url: str,
        patience_s: float = STORAGE_PATIENCE_S,
        *,
        grace_s: float,
        stopping: Callable[[], bool] = lambda: False,
    ) -> None:
        self.url = url
        self.patience_s = check_storage_patience(patience_s)
        self.grace_s = grace_s
        self.stopping = stopping
        self._last_failure = -float("inf")

    def failed(self) -> None:
        """Note a failure to reach the storage seen elsewhere (a heartbeat thread)."""
        self._last_failure = time.monotonic()

    def __call__(self, step: Callable[[], _T]) -> _T:
        since = None
        longest = max(0.1, min(_RETRY_S[1], self.grace_s / 3))
        wait_s = min(_RETRY_S[0], longest)
        while True:
            try:
                result = step()
            except Exception as error:
                if not unreachable(error):
                    raise
                self.failed()
                if since is None:
                    since = self._last_failure
                    logger.warning(
                        "the storage %s cannot be reached; trying again for up to %g s "
                        "(--storage-patience)",
                        redacted_url(self.url),
                        self.patience_s,
                    )
                waited = time.monotonic() - since
                if waited >= self.patience_s or self.stopping():
                    reason = storage_error_message(error, self.url) or str(error)
                    raise StorageError(
                        f"{reason} (unreachable for {waited:.0f} s; --storage-patience "
                        f"{self.patience_s:g} s)"
                    ) from error
                self._sleep(min(wait_s, self.patience_s - waited))
                wait_s = min(2 * wait_s, longest)
                continue
            if since is not None:
                logger.warning(
                    "the storage %s is back after %.0f s",
                    redacted_url(self.url),
                    time.monotonic() - since,
                )
            return result

    def _sleep(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while not self.stopping() and time.monotonic() < end:
            time.sleep(min(0.2, max(0.0, end - time.monotonic())))

    def stale_check(self, study: optuna.Study) -> None:
        """:func:`stale_trial_check`, unless the storage was unreachable within the grace."""
        if time.monotonic() - self._last_failure > self.grace_s:
            self(lambda: stale_trial_check(study))
