"""The journal's write lock (``surrogate.storage._lock``): a writer killed inside it no
longer holds up the others for Optuna's 30 s grace; a live writer, ours or Optuna's, is
never taken for dead, however long it holds the lock."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from optuna.storages.journal import JournalFileSymlinkLock

from surrogate.storage import _lock
from surrogate.storage._lock import GRACE_S, JournalLock

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def journal(tmp_path):
    path = tmp_path / "study.log"
    path.write_text("")
    return str(path)


def die_inside_the_lock(journal, *, fork_a_child=False):
    """A process that takes the lock and is SIGKILLed holding it; the pid of the child it
    forked first (which outlives it) if ``fork_a_child``."""
    script = textwrap.dedent(
        f"""
        import os, signal, time
        from surrogate.storage._lock import JournalLock
        lock = JournalLock({journal!r})
        lock.acquire()
        if {fork_a_child!r}:
            child = os.fork()
            if child == 0:
                os.close(1), os.close(2)  # the pipes: the parent's output ends with it
                time.sleep(60)
                os._exit(0)
            print(child, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == -9, done.stderr
    assert os.path.islink(journal + ".lock")  # left behind, as a killed writer leaves it
    return int(done.stdout) if fork_a_child else None


def _acquire_timed(lock):
    start = time.monotonic()
    lock.acquire()
    try:
        return time.monotonic() - start
    finally:
        lock.release()


def test_a_writer_killed_inside_the_lock_does_not_hold_up_the_next(journal):
    die_inside_the_lock(journal)
    waited = _acquire_timed(JournalLock(journal))
    assert waited < GRACE_S / 10  # Optuna's lock alone: the grace
    assert not os.path.lexists(journal + ".lock")


@pytest.mark.filterwarnings("ignore:The value of `grace_period` might be too small")
def test_a_symlink_without_a_record_of_a_dead_holder_keeps_optunas_grace(journal):
    """A symlink no writer of ours recorded (an Optuna writer's, another machine's): its
    holder may be alive, so it is removed only after the grace with the journal
    unchanged — here a grace of 1 s."""
    os.symlink(journal, journal + ".lock")
    waited = _acquire_timed(JournalLock(journal, grace_s=1))
    assert waited >= 1.0


def test_a_child_forked_inside_the_lock_does_not_keep_it_after_its_parent_dies(journal):
    child = die_inside_the_lock(journal, fork_a_child=True)
    try:
        waited = _acquire_timed(JournalLock(journal))
    finally:
        os.kill(child, 9)
    assert waited < GRACE_S / 10  # with the inherited descriptor open: 2 × the grace


def _hold(lock, seconds, released):
    lock.acquire()
    time.sleep(seconds)
    released.append(time.monotonic())
    lock.release()


@pytest.mark.parametrize(
    ("first", "second"),
    [
        (JournalLock, JournalLock),
        (JournalFileSymlinkLock, JournalLock),  # the Optuna CLI's or dashboard's lock
        (JournalLock, JournalFileSymlinkLock),
    ],
)
def test_a_live_holder_keeps_the_lock_until_it_releases_it(journal, first, second):
    """Held 1.5 s without writing, longer than any wait of ours but Optuna's grace."""
    released: list[float] = []
    thread = threading.Thread(target=_hold, args=(first(journal), 1.5, released))
    thread.start()
    while not os.path.lexists(journal + ".lock"):
        time.sleep(0.001)
    waiting = second(journal)
    waiting.acquire()
    acquired = time.monotonic()
    waiting.release()
    thread.join()
    assert released and acquired >= released[0]


def test_where_the_file_system_has_no_flock_the_symlink_lock_alone_guards(journal, monkeypatch):
    def no_flock(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(_lock.fcntl, "flock", no_flock)
    lock = JournalLock(journal)
    lock.acquire()
    assert os.path.islink(journal + ".lock") and lock._fd is None
    lock.release()
    assert not os.path.lexists(journal + ".lock")
