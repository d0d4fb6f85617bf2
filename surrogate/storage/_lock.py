"""The journal file's write lock: a kernel lock that dies with its holder, then Optuna's.

Optuna guards a journal with :class:`~optuna.storages.journal.JournalFileSymlinkLock`,
a symlink ``<journal>.lock`` that a writer creates and removes around each append. A
writer killed inside (SIGKILL, the OOM killer) leaves the symlink behind, and every
other writer then waits out its grace period (30 s) without writing — heartbeats
included, so a live trial went stale and was failed and queued again.

:class:`JournalLock` takes ``flock`` on ``<journal>.flock`` first. The kernel drops
that lock when its holder dies, and a writer holding it knows that no writer of ours
holds the symlink. Then it takes the symlink, which the Optuna CLI and
``optuna-dashboard`` take on their own, so the journal is still theirs to write.
A symlink that stays put while the journal does not change for
:data:`DEAD_HOLDER_S` is therefore a dead writer's (a live Optuna writer holds it for
one append) and is removed the way Optuna releases it.

Where the kernel lock cannot be had — a file system without ``flock`` (some NFS
mounts), or a holder alive but frozen (SIGSTOP) for Optuna's grace period — the
writer falls back to the symlink lock alone, Optuna's own behaviour.
"""

from __future__ import annotations

import errno
import fcntl
import os
import time
import weakref
from collections.abc import Iterator

from optuna.storages.journal import JournalFileSymlinkLock

__all__ = ["DEAD_HOLDER_S", "JournalLock"]

DEAD_HOLDER_S = 1.0
"""How long [s] a symlink may stay with the journal unchanged while the kernel lock is
held before it is taken for a dead writer's. Below a heartbeat's grace (3 s at the
shortest), so a dead writer's lock no longer makes a live trial stale."""

GRACE_S = 30
"""Optuna's grace period [s]: the symlink lock alone breaks a lock unchanged this long."""

_POLL_S = (0.001, 0.05)  # first and longest sleep between tries

_HELD: weakref.WeakSet[JournalLock] = weakref.WeakSet()  # locks whose kernel lock is held


def _let_go_of_inherited_locks() -> None:
    """In a forked child: close the kernel-lock descriptors it inherited.

    A descriptor shared with the parent keeps the flock alive as long as either process
    holds it; a child outliving a killed parent would otherwise keep the lock. Closing
    the child's copy leaves the parent's lock as it is.
    """
    for lock in list(_HELD):
        if lock._fd is not None:
            os.close(lock._fd)
            lock._fd = None
    _HELD.clear()


os.register_at_fork(after_in_child=_let_go_of_inherited_locks)


class JournalLock(JournalFileSymlinkLock):
    """``flock`` on ``<journal>.flock``, then Optuna's symlink ``<journal>.lock``
    (whose creation, removal and grace period are :class:`JournalFileSymlinkLock`'s).

    Parameters
    ----------
    journal : str
        The journal file's path.
    dead_holder_s : float
        See :data:`DEAD_HOLDER_S`.
    grace_s : int
        Optuna's grace period, for the symlink lock alone (see the module docstring).
    """

    def __init__(
        self, journal: str, *, dead_holder_s: float = DEAD_HOLDER_S, grace_s: int = GRACE_S
    ) -> None:
        super().__init__(journal, grace_period=grace_s)
        self._journal = journal
        self._link = self._lock_file  # Optuna's name for it: <journal>.lock
        self._kernel_file = journal + ".flock"
        self._dead_holder_s = dead_holder_s
        self._grace_s = grace_s
        self._fd: int | None = None

    def acquire(self) -> bool:
        try:
            if not self._kernel_lock():
                return super().acquire()
            self._take_symlink()
        except BaseException:
            self._kernel_unlock()
            raise
        return True

    def release(self) -> None:
        try:
            super().release()
        finally:
            self._kernel_unlock()

    def _kernel_lock(self) -> bool:
        """Take the kernel lock; False where it cannot be had (module docstring)."""
        try:
            fd = os.open(self._kernel_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError:
            return False  # e.g. a read-only folder: the symlink lock says what is wrong
        deadline = time.monotonic() + self._grace_s
        for sleep_s in _backoff():
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                self._fd = fd
                _HELD.add(self)
                return True
            except OSError as error:
                if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                    break  # ENOLCK, EOPNOTSUPP: no flock on this file system
                if time.monotonic() > deadline:
                    break  # its holder lives but does not finish: Optuna's rule
            time.sleep(sleep_s)
        os.close(fd)
        return False

    def _kernel_unlock(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            _HELD.discard(self)
            try:
                fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)

    def _take_symlink(self) -> None:
        """Create the symlink, removing one that stays as a dead writer's would."""
        seen, since = None, time.monotonic()
        for sleep_s in _backoff():
            try:
                os.symlink(self._journal, self._link)
                return
            except FileExistsError:
                pass
            holder = _holder_state(self._link, self._journal)
            if holder != seen:  # another holder, or the journal written since
                seen, since = holder, time.monotonic()
            elif time.monotonic() - since > self._dead_holder_s:
                try:
                    super().release()  # rename, then unlink: Optuna's own removal
                except RuntimeError:
                    pass  # its holder released it after all
                seen, since = None, time.monotonic()
                continue
            time.sleep(sleep_s)


def _holder_state(link: str, journal: str) -> tuple[int, int] | None:
    """The symlink's inode and the journal's modification time (None if either is gone)."""
    try:
        return os.lstat(link).st_ino, os.stat(journal).st_mtime_ns
    except OSError:
        return None


def _backoff() -> Iterator[float]:
    sleep_s = _POLL_S[0]
    while True:
        yield sleep_s
        sleep_s = min(2 * sleep_s, _POLL_S[1])
