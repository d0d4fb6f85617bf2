"""The one process pool: a function over tasks in worker processes, results as they finish.

One start method for every parallel part of the package (batch evaluation, the
calibration's solver runs, the diagnosis's refits, verification workers):
``fork`` on Linux — fast, and effects and solvers registered in this process
(plug-ins, or in code) exist in the children too; database connections a child
inherits are let go of at the fork (:mod:`surrogate.storage._storage`). Each child
limits its BLAS to one thread: several processes each spinning a BLAS thread pool
on the same cores run about ten times slower. Elsewhere (macOS, where fork is
unsafe with the system's libraries; Windows, which has none) a task pool runs
serially in this process rather than losing registered plug-ins, and worker
processes are spawned.
"""

from __future__ import annotations

import functools
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, ParamSpec, TypeVar

from ._errors import InputDataError

__all__ = [
    "can_fork",
    "catch_signal",
    "check_jobs",
    "cpu_jobs",
    "imap_unordered",
    "one_blas_thread",
    "one_blas_thread_within",
    "process_context",
    "worker_count",
]

T = TypeVar("T")
R = TypeVar("R")
P = ParamSpec("P")


def can_fork() -> bool:
    return sys.platform.startswith("linux")


def process_context() -> Any:
    """The multiprocessing context of every child process the package starts."""
    return multiprocessing.get_context("fork" if can_fork() else "spawn")


def catch_signal(signum: int, handler: Callable[[int, Any], Any]) -> Any:
    """``handler`` for ``signum`` in this process, unless the process ignores it; the
    handler it replaced, None where it installed none. An ignored signal stays ignored,
    as Python leaves it: a shell script's background job starts with SIGINT ignored, so a
    Ctrl-C meant for the script's foreground does not stop it. Catching it in one part of
    a command only (the worker loop had) made ``surrogate run`` stop at some Ctrl-Cs and
    run on through others."""
    if signal.getsignal(signum) is signal.SIG_IGN:
        return None
    return signal.signal(signum, handler)


def one_blas_thread() -> None:
    """Initializer of every child: one BLAS thread (see the module docstring)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def one_blas_thread_within(function: Callable[P, R]) -> Callable[P, R]:
    """``function`` run with one BLAS thread in this process, the caller's setting
    restored after: what it computes does not depend on the machine's number of cores.
    OpenBLAS splits some of its work by thread, and the rounding with it: the same
    calibration with two threads and with one ended 2.3e-9 N apart in its RMSE (and a
    chaotic one on another path). One thread as in every child process
    (:func:`one_blas_thread`); the package's matrices are small (a few hundred runs),
    where threads gain little. The limit is the process's: two calls at once in two
    threads of one process share it."""

    @functools.wraps(function)
    def limited(*args: P.args, **kwargs: P.kwargs) -> R:
        with _blas_controller().limit(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return limited


@functools.cache
def _blas_controller() -> Any:
    """The BLAS libraries of NumPy and SciPy, looked up once (0.05 ms a limit, not the
    2–9 ms of a fresh look-up at every call)."""
    import scipy.linalg  # noqa: F401  (SciPy's own OpenBLAS, loaded before the look-up)
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def check_jobs(jobs: Any, *, minimum: int = 1, every_cpu: bool = False) -> Any:
    """``--jobs``: a whole number ≥ ``minimum`` (None too where ``every_cpu``: all CPUs);
    else the one-line error every command and API function gives."""
    if jobs is None and every_cpu:
        return jobs
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < minimum:
        raise InputDataError(f"--jobs must be ≥ {minimum}, got {jobs!r}")
    return jobs


def cpu_jobs(jobs: int | None) -> int:
    """``jobs``, or every core when None."""
    if jobs is not None:
        check_jobs(jobs)
    return jobs or os.cpu_count() or 1


def worker_count(jobs: int | None, tasks: int) -> int:
    """Processes for ``tasks`` tasks: ``jobs`` (all cores when None), never more than tasks."""
    return max(1, min(cpu_jobs(jobs), tasks))


def imap_unordered(
    function: Callable[[T], R], tasks: Sequence[T], jobs: int
) -> Iterator[tuple[int, R]]:
    """``(index, function(tasks[index]))`` for every task, in the order they finish.

    ``jobs`` = 1 (or one task, or no ``fork``) runs in this process; else at most one
    process a task (a pool that forks starts all its processes at once: three runs with
    ``jobs`` = 64 would fork 64). At most ``2 × jobs`` tasks are submitted ahead, so an
    interrupt cancels the rest at once; an exception in a task (or here) shuts the pool
    down without waiting.
    """
    check_jobs(jobs)
    if jobs == 1 or len(tasks) <= 1 or not can_fork():
        for index, task in enumerate(tasks):
            yield index, function(task)
        return
    with ProcessPoolExecutor(
        max_workers=min(jobs, len(tasks)),
        mp_context=process_context(),
        initializer=one_blas_thread,
    ) as pool:
        pending: dict[Future[R], int] = {}
        queue = list(range(len(tasks)))
        queue.reverse()
        try:
            while queue or pending:
                while queue and len(pending) < 2 * jobs:
                    index = queue.pop()
                    pending[pool.submit(function, tasks[index])] = index
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield pending.pop(future), future.result()
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
