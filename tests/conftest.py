import os
from pathlib import Path
from typing import Any

import pytest
from threadpoolctl import threadpool_limits

# One BLAS thread a test process, and in the processes tests start: the suite runs a pytest
# process a core and one more (pytest-xdist, below), and on this product's small matrices a second
# OpenBLAS thread only spins (test_diagnose's tension case, alone on the 2-core machine:
# 49 s wall and 50 s CPU with one thread, 59 s and 95 s with two). The results do not
# depend on it (tests/test_calibrate_sweep.py runs both thread counts on purpose).
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_variable] = "1"  # also where a test compares a subprocess with this one
threadpool_limits(1)

REPO = Path(__file__).resolve().parents[1]
# Verification tables live in the steering repo's shared/ folder beside this one;
# a copy is kept in tests/reference so a clone runs on its own.
REFERENCE = REPO / "tests" / "reference"


# How scripts/test.sh (``-n auto --dist loadgroup``) spreads the tests over its processes:
# - The tests that mostly wait (on workers' heartbeats, Slurm's scheduler, a database
#   restarted under them) run one after another in a process of their own, beside one
#   process a core for the rest, so the cores are busy while they wait: alone, one after
#   another, tests/cluster and tests/workers took 316 s and used 135 s of CPU (42 % of a
#   core; 2-core AMD EPYC, 2026-12-06). The group is named by path in the scheduler below:
#   pytest-xdist 3.8 names a group from ``xdist_group`` marks by rewriting ``item._nodeid``,
#   which pytest 9.2 no longer reads (every marked test ran on its own).
# - The slow tests are sent first, so the last ones to finish are short.
WAITING = ("tests/cluster/", "tests/workers/")


@pytest.hookimpl(tryfirst=True, optionalhook=True)  # optional: pytest-xdist's hook
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """``--dist loadgroup``: xdist's scheduling of groups, the group being WAITING's tests."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class WaitingApart(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return "waiting" if nodeid.startswith(WAITING) else nodeid

    return WaitingApart(config, log)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # stable


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: one pytest process a core, and one for the tests that mostly wait."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (cores or 1) + 1


@pytest.fixture(scope="session")
def reference_dir() -> Path:
    return REFERENCE


class CountingSolve:
    """A full-solver stand-in that counts its calls and can be interrupted.

    It runs the real solver; after ``stop_after`` calls it raises
    KeyboardInterrupt, as a user pressing Ctrl-C mid-batch would.
    """

    def __init__(self, stop_after=None):
        self.calls = 0
        self.stop_after = stop_after

    def __call__(self, inputs):
        from surrogate.solvers._batch import solve_inputs

        if self.stop_after is not None and self.calls >= self.stop_after:
            raise KeyboardInterrupt
        self.calls += 1
        return solve_inputs(inputs)


from tests.fidelity import distorted_solver  # noqa: E402, F401  (a fixture: the test-only solver)
