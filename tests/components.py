"""Real components the system tests need (PostgreSQL, Chromium): find or give up.

In CI (``CI=true``) a missing component fails the test; elsewhere it skips with
the reason. ``scripts/system-packages.sh`` installs both when run as root.
"""

from __future__ import annotations

import glob
import os
import shutil
import socket
from pathlib import Path

import pytest

INSTALL = "run scripts/system-packages.sh as root (Debian: apt-get install postgresql chromium)"


def missing(reason: str) -> None:
    """Fail in CI, skip elsewhere."""
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{reason} (CI=true: a missing component is a failure)", pytrace=False)
    pytest.skip(reason)


def postgres_bin_dir() -> Path | None:
    """A folder with initdb, pg_ctl and postgres (PATH first, then Debian's layout)."""
    candidates = []
    if shutil.which("initdb"):
        candidates.append(Path(shutil.which("initdb")).resolve().parent)
    candidates += [
        Path(d)
        for d in sorted(
            glob.glob("/usr/lib/postgresql/*/bin"),
            key=lambda d: int(Path(d).parent.name) if Path(d).parent.name.isdigit() else 0,
            reverse=True,
        )
    ]
    for folder in candidates:
        if all(os.access(folder / name, os.X_OK) for name in ("initdb", "pg_ctl", "postgres")):
            return folder
    return None


def chromium_binary() -> str | None:
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return "/usr/bin/chromium" if os.access("/usr/bin/chromium", os.X_OK) else None


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]
