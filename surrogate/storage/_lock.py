"""The journal file's write lock: Optuna's symlink lock, whose dead holder is recognised.

Optuna guards a journal with :class:`~optuna.storages.journal.JournalFileSymlinkLock`,
a symlink ``<journal>.lock`` that a writer creates and removes around each append. A
writer killed inside (SIGKILL, the OOM killer) leaves the symlink behind, and every
other writer then waits out its grace period (30 s) without writing — heartbeats
included, so a live trial went stale and was failed and queued again.

:class:`JournalLock` takes ``flock`` on ``<journal>.flock`` first; the kernel drops
it when its holder dies. Holding it, a writer creates the symlink — which the Optuna
CLI and ``optuna-dashboard`` take on their own, so the journal stays theirs to write —
and writes into ``<journal>.flock`` who holds it: the machine, the process id and the
symlink's inode (cleared again before the symlink is removed). A writer that finds
the symlink there, and the record naming that very symlink and a process of this
machine that is no longer alive, removes it at once (as Optuna removes a lock). Any
other symlink — another machine's, an Optuna writer's, one whose holder may be alive —
keeps Optuna's grace period: nothing is judged dead by time alone.

Where the kernel lock cannot be had — a file system without ``flock``, a ``.flock``
file this user cannot open, or a holder alive but frozen (SIGSTOP) for Optuna's grace
period — the writer takes the symlink lock alone, Optuna's own behaviour; after a
holder froze, later appends try the kernel lock once and do not wait for it again.
"""

from __future__ import annotations

import errno
import fcntl
import os
import socket
import time
import weakref
from collections.abc import Iterator

from optuna.storages.journal import JournalFileSymlinkLock

__all__ = ["GRACE_S", "JournalLock"]

GRACE_S = 30
"""Optuna's grace period [s]: a symlink with the journal unchanged this long is broken."""

_POLL_S = (0.001, 0.05)  # first and longest sleep between tries
_RECORD_BYTES = 256

_OPEN: weakref.WeakSet[JournalLock] = weakref.WeakSet()  # locks with a kernel-lock descriptor


def _let_go_of_inherited_locks() -> None:
    """In a forked child: close the kernel-lock descriptors it inherited.

    A descriptor shared with the parent keeps the flock alive as long as either process
    holds it; a child outliving a killed parent would otherwise keep the lock. Closing
    the child's copy leaves the parent's lock as it is.
    """
    for lock in list(_OPEN):
        if lock._fd is not None:
            os.close(lock._fd)
            lock._fd = None
    _OPEN.clear()


os.register_at_fork(after_in_child=_let_go_of_inherited_locks)


def _this_machine() -> str:
    """The host and its PID namespace: where a process id means one process."""
    try:
        namespace = os.stat("/proc/self/ns/pid").st_ino
    except OSError:
        namespace = 0
    return f"{socket.gethostname()}/{namespace}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


class JournalLock(JournalFileSymlinkLock):
    """``flock`` on ``<journal>.flock``, then Optuna's symlink ``<journal>.lock``
    (whose creation, removal and grace period are :class:`JournalFileSymlinkLock`'s).

    Parameters
    ----------
    journal : str
        The journal file's path.
    grace_s : int
        Optuna's grace period (module docstring).
    """

    def __init__(self, journal: str, *, grace_s: int = GRACE_S) -> None:
        super().__init__(journal, grace_period=grace_s)
        self._journal = journal
        self._link = self._lock_file  # Optuna's name for it: <journal>.lock
        self._kernel_file = journal + ".flock"
        self._grace_s = grace_s
        self._fd: int | None = None
        self._kernel_lock_stuck = False  # its last holder did not let go within the grace

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
            if self._fd is not None:
                os.ftruncate(self._fd, 0)  # a record names only a symlink still held
            super().release()
        finally:
            self._kernel_unlock()

    def _kernel_lock(self) -> bool:
        """Take the kernel lock; False where it cannot be had (module docstring)."""
        try:
            self._fd = os.open(self._kernel_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError:
            return False  # e.g. a read-only folder: the symlink lock says what is wrong
        _OPEN.add(self)
        deadline = time.monotonic() + (0.0 if self._kernel_lock_stuck else self._grace_s)
        for sleep_s in _backoff():
            try:
                fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                self._kernel_lock_stuck = False
                return True
            except OSError as error:
                if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                    break  # ENOLCK, EOPNOTSUPP: no flock on this file system
                if time.monotonic() >= deadline:
                    self._kernel_lock_stuck = True  # its holder lives and does not finish
                    break
            time.sleep(sleep_s)
        self._kernel_unlock(held=False)
        return False

    def _kernel_unlock(self, *, held: bool = True) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            _OPEN.discard(self)
            try:
                if held:
                    fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)

    def _take_symlink(self) -> None:
        """Create the symlink and record its holder; remove a dead holder's at once and
        any other after Optuna's grace (the journal unchanged that long)."""
        assert self._fd is not None
        seen, since = None, time.monotonic()
        for sleep_s in _backoff():
            try:
                os.symlink(self._journal, self._link)
            except FileExistsError:
                pass
            else:
                record = f"{_this_machine()} {os.getpid()} {os.lstat(self._link).st_ino}\n"
                os.ftruncate(self._fd, 0)
                os.pwrite(self._fd, record.encode(), 0)
                return
            holder = _holder_state(self._link, self._journal)
            if holder != seen:  # another holder, or the journal written since
                seen, since = holder, time.monotonic()
            if self._holder_is_dead() or time.monotonic() - since > self._grace_s:
                try:
                    super().release()  # rename, then unlink: Optuna's own removal
                except RuntimeError:
                    pass  # its holder released it after all
                seen, since = None, time.monotonic()
                continue
            time.sleep(sleep_s)

    def _holder_is_dead(self) -> bool:
        """The record names this symlink and a process of this machine that is gone."""
        assert self._fd is not None
        try:
            machine, pid, inode = os.pread(self._fd, _RECORD_BYTES, 0).decode().split()
            return (
                machine == _this_machine()
                and int(inode) == os.lstat(self._link).st_ino
                and not _alive(int(pid))
            )
        except (OSError, ValueError):
            return False  # no record, or the symlink has just gone


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
