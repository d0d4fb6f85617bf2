"""A throwaway PostgreSQL server for the session (127.0.0.1, a free port)."""

from __future__ import annotations

import itertools
import os
import pwd
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

from tests.components import INSTALL, free_port, missing, postgres_bin_dir

_databases = itertools.count()


def _as_server_user(command: list[str]) -> list[str]:
    """postgres refuses to run as root: run it as the ``postgres`` user then."""
    if os.geteuid() != 0:
        return command
    return ["runuser", "-u", "postgres", "--", *command]


@pytest.fixture(scope="session")
def postgres_server():
    """``postgresql://surrogate@127.0.0.1:PORT``; stopped and deleted afterwards."""
    bindir = postgres_bin_dir()
    if bindir is None:
        missing(f"PostgreSQL (initdb, pg_ctl, postgres) not found; {INSTALL}")
    if os.geteuid() == 0:
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            missing("running as root and there is no 'postgres' user to run the server")
        if shutil.which("runuser") is None:
            missing("running as root and runuser is missing")
    folder = Path(tempfile.mkdtemp(prefix="surrogate-pg-"))
    data = folder / "data"
    if os.geteuid() == 0:
        os.chown(folder, user.pw_uid, user.pw_gid)
    port = free_port()

    def run(*args: str) -> None:
        command = _as_server_user([str(bindir / args[0]), *args[1:]])
        subprocess.run(command, check=True, capture_output=True, text=True, timeout=120)

    try:
        run("initdb", "-D", str(data), "-U", "surrogate", "-A", "trust", "-E", "UTF8", "--no-sync")
        options = (
            f"-c listen_addresses=127.0.0.1 -p {port} -k {folder} "
            "-c fsync=off -c synchronous_commit=off -c full_page_writes=off "
            "-c max_connections=100"
        )
        run("pg_ctl", "-D", str(data), "-o", options, "-l", str(folder / "log"), "-w", "start")
    except subprocess.CalledProcessError as error:
        shutil.rmtree(folder, ignore_errors=True)
        pytest.fail(f"PostgreSQL did not start: {error.stderr or error.stdout}", pytrace=False)
    try:
        yield f"postgresql://surrogate@127.0.0.1:{port}"
    finally:
        subprocess.run(
            _as_server_user([str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"]),
            capture_output=True,
            timeout=60,
        )
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def postgres_url(postgres_server):
    """A fresh, empty database on the session's server."""
    import psycopg

    name = f"t{os.getpid()}_{next(_databases)}"
    with psycopg.connect(f"{postgres_server}/postgres", autocommit=True) as connection:
        connection.execute(f'CREATE DATABASE "{name}"')
    return f"{postgres_server}/{name}"


@pytest.fixture(params=["journal", "postgresql"])
def storage_url(request, tmp_path):
    """Each worker test on the journal file and on PostgreSQL."""
    if request.param == "journal":
        return f"journal://{tmp_path / 'study.log'}"
    return request.getfixturevalue("postgres_url")
