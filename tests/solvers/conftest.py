"""CalculiX tests run wherever ``ccx`` is installed; in CI (``CI=true``) a missing
``ccx`` is a failure, not a skip (``scripts/system-packages.sh`` installs it)."""

import os
import shutil

import pytest


@pytest.fixture(scope="session")
def ccx() -> str:
    path = shutil.which("ccx")
    if path is None:
        reason = "CalculiX (ccx) is not installed: apt-get install calculix-ccx"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{reason} — CI requires it (scripts/system-packages.sh)")
        pytest.skip(reason)
    return path
