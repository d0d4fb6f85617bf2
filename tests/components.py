"""Real components the system tests need (PostgreSQL, Chromium): find or give up.

In CI (``CI=true``) a missing component fails the test; elsewhere it skips with
the reason. ``scripts/system-packages.sh`` installs both when run as root.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import pwd
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator
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


class ComponentMissing(RuntimeError):
    """A real component a test or benchmark needs is not installed."""


def _as_server_user(command: list[str]) -> list[str]:
    """postgres refuses to run as root: run it as the ``postgres`` user then."""
    return ["runuser", "-u", "postgres", "--", *command] if os.geteuid() == 0 else command


@contextlib.contextmanager
def throwaway_postgres() -> Iterator[str]:
    """Start a PostgreSQL server in a temporary folder; yield its URL (no database).

    It listens on 127.0.0.1 only, on a free port, with trust authentication for
    the user ``surrogate``; it is stopped and its folder deleted afterwards.
    """
    bindir = postgres_bin_dir()
    if bindir is None:
        raise ComponentMissing(f"PostgreSQL (initdb, pg_ctl, postgres) not found; {INSTALL}")
    folder = Path(tempfile.mkdtemp(prefix="surrogate-pg-"))
    if os.geteuid() == 0:
        if shutil.which("runuser") is None:
            raise ComponentMissing("running as root and runuser is missing")
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            raise ComponentMissing("running as root and there is no 'postgres' user") from None
        os.chown(folder, user.pw_uid, user.pw_gid)
    data, port = folder / "data", free_port()

    def run(*args: str) -> None:
        command = _as_server_user([str(bindir / args[0]), *args[1:]])
        subprocess.run(command, check=True, capture_output=True, text=True, timeout=120, cwd=folder)

    try:
        run("initdb", "-D", str(data), "-U", "surrogate", "-A", "trust", "-E", "UTF8", "--no-sync")
        options = (
            f"-c listen_addresses=127.0.0.1 -p {port} -k {folder} "
            "-c fsync=off -c synchronous_commit=off -c full_page_writes=off"
        )

        def start() -> None:
            run("pg_ctl", "-D", str(data), "-o", options, "-l", str(folder / "log"), "-w", "start")

        start()
        url = f"postgresql://surrogate@127.0.0.1:{port}"
        _CONTROLS[url] = {
            "start": start,
            "stop": lambda: run("pg_ctl", "-D", str(data), "-w", "stop"),
        }
        yield url
    finally:
        _CONTROLS.pop(f"postgresql://surrogate@127.0.0.1:{port}", None)
        if (data / "postmaster.pid").exists():
            subprocess.run(
                _as_server_user(
                    [str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"]
                ),
                capture_output=True,
                timeout=60,
            )
        shutil.rmtree(folder, ignore_errors=True)


_CONTROLS: dict[str, dict[str, Callable[[], None]]] = {}


def postgres_control(server_url: str, action: str) -> None:
    """``stop`` (fast shutdown: sessions are cut) or ``start`` again a server that
    :func:`throwaway_postgres` started in this process."""
    _CONTROLS[server_url][action]()


def create_database(server_url: str, name: str) -> str:
    """A new empty database on ``server_url``; returns its URL."""
    import psycopg

    with psycopg.connect(f"{server_url}/postgres", autocommit=True) as connection:
        connection.execute(f'CREATE DATABASE "{name}"')
    return f"{server_url}/{name}"


class Dashboard:
    """``surrogate dashboard STUDY [--storage URL] --port P`` in a subprocess, and its
    JSON API (a context manager: the server is stopped at the end)."""

    def __init__(self, study: str | os.PathLike[str], storage: str | None = None) -> None:
        self.port = free_port()
        where = ["--storage", storage] if storage else []
        self.server = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "surrogate",
                "dashboard",
                str(study),
                *where,
                "--port",
                str(self.port),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def __enter__(self) -> Dashboard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.terminate()
        self.server.wait(timeout=10)

    def studies(self) -> list[dict]:
        """The study summaries, once the server answers: up to 180 s while it runs (its
        start is imports, slow on a loaded machine; 15 s failed with two suites on two
        cores), at once with its stderr if it ended."""
        deadline = time.monotonic() + 180.0
        while time.monotonic() < deadline:
            try:
                return self.get("/api/studies")["study_summaries"]
            except OSError:
                if self.server.poll() is not None:  # it ended: no point waiting
                    break
                time.sleep(0.25)
        ended = self.server.poll()
        raise AssertionError(
            f"the dashboard did not answer on 127.0.0.1 (exit code {ended}; "
            f"{self.server.stderr.read() if ended is not None else 'still running'})"
        )

    def detail(self, study_name: str) -> dict:
        """The dashboard's view of one study (trials, figures, note)."""
        study_id = next(s["study_id"] for s in self.studies() if s["study_name"] == study_name)
        return self.get(f"/api/studies/{study_id}?after=0")

    def get(self, path: str) -> dict:
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}{path}", timeout=5) as r:
            return json.load(r)
