"""Storage URLs: which name a file, which live only in this process's memory."""

from __future__ import annotations

from pathlib import Path

import optuna
import pytest

from surrogate._errors import InputDataError
from surrogate.storage._storage import (
    check_workers,
    in_memory_storage,
    local_storage_file,
    open_storage,
)


@pytest.mark.parametrize(
    ("url", "memory", "local"),
    [
        ("sqlite://", True, None),
        ("sqlite:///:memory:", True, None),
        ("sqlite:///file:shared?mode=memory&cache=shared&uri=true", True, None),
        ("sqlite:///file::memory:?cache=shared&uri=true", True, None),
        ("sqlite:///study.db", False, Path("study.db")),
        ("sqlite+pysqlite:///study.db", False, Path("study.db")),
        ("sqlite:////srv/runs/study.db", False, Path("/srv/runs/study.db")),
        ("sqlite:///file:runs/study.db?uri=true", False, Path("runs/study.db")),
        # files named so, or a mode SQLite reads only in a URI filename
        ("sqlite:///memory.db", False, Path("memory.db")),
        ("sqlite:///:memory:.db", False, Path(":memory:.db")),
        ("sqlite:///runs/mode=memory.db", False, Path("runs/mode=memory.db")),
        ("sqlite:///study.db?mode=memory", False, Path("study.db")),
        ("journal:///srv/study.log", False, Path("/srv/study.log")),
        ("postgresql://user@host/db", False, None),
    ],
)
def test_an_in_memory_database_has_no_file(url, memory, local):
    assert in_memory_storage(url) is memory
    assert local_storage_file(url) == local


def test_an_in_memory_database_serves_one_process_and_refuses_workers():
    storage = open_storage("sqlite://")  # the whole job in this process: allowed
    study = optuna.create_study(study_name="s", storage=storage)
    study.enqueue_trial({"x": 1.0})
    assert len(study.trials) == 1
    check_workers("sqlite://", 1)
    for workers, says in ((0, "the workers --jobs 0 plans for"), (3, "--jobs 3 workers")):
        with pytest.raises(InputDataError, match=says):
            check_workers("sqlite:///:memory:", workers)
    with pytest.raises(InputDataError, match="so a worker would find nothing in it"):
        open_storage("sqlite://", heartbeat_s=1, must_exist=True)
