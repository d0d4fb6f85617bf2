from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# Verification tables live in the steering repo's shared/ folder beside this one;
# a copy is kept in tests/reference so a clone runs on its own.
REFERENCE = REPO / "tests" / "reference"


@pytest.fixture(scope="session")
def reference_dir() -> Path:
    return REFERENCE
