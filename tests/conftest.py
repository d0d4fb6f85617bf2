from pathlib import Path

import pytest

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
