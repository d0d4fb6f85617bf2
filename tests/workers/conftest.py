"""A throwaway PostgreSQL server for the session (127.0.0.1, a free port)."""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.components import ComponentMissing, create_database, missing, throwaway_postgres

_databases = itertools.count()
STUDIES = Path(__file__).resolve().parents[2] / "studies"


@pytest.fixture(scope="session")
def postgres_server():
    """``postgresql://surrogate@127.0.0.1:PORT``; stopped and deleted afterwards."""
    try:
        server = throwaway_postgres()
        url = server.__enter__()
    except ComponentMissing as error:
        missing(str(error))
    except subprocess.CalledProcessError as error:
        pytest.fail(f"PostgreSQL did not start: {error.stderr or error.stdout}", pytrace=False)
    try:
        yield url
    finally:
        server.__exit__(None, None, None)


@pytest.fixture
def postgres_url(postgres_server):
    """A fresh, empty database on the session's server."""
    return create_database(postgres_server, f"t{os.getpid()}_{next(_databases)}")


@pytest.fixture(params=["journal", "postgresql"])
def storage_url(request, tmp_path):
    """Each worker test on the journal file and on PostgreSQL."""
    if request.param == "journal":
        return f"journal://{tmp_path / 'study.log'}"
    return request.getfixturevalue("postgres_url")


@pytest.fixture
def study_file(tmp_path):
    """The shipped paper study, copied (its folder holds the cache and the storage)."""
    path = tmp_path / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", path)
    return path
