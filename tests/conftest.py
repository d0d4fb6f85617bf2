import os
from pathlib import Path

import pytest
from threadpoolctl import threadpool_limits

# One BLAS thread a test process, and in the processes tests start: the suite runs one
# pytest process a core (pytest-xdist), and on this product's small matrices a second
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
