"""A storage that cannot be written (read-only, full) is one line and exit 2, not a
traceback, and the storage is left as it was."""

from __future__ import annotations

import hashlib
import resource
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from surrogate.identify._doe import make_design
from surrogate.identify._verify import enqueue, open_verify_study
from surrogate.study._spec import load_study

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


@pytest.fixture
def study_file(tmp_path):
    path = tmp_path / "paper_coating.toml"
    shutil.copy(REPO / "studies" / "paper_coating.toml", path)
    return path


def _plan(study_file, storage_url):
    spec = load_study(study_file)
    study = open_verify_study(spec, storage_url, heartbeat_s=None)
    points = make_design("lhs", spec.space, n=3, seed=0).to_dict("records")
    enqueue(study, spec, points, phase="plan")


def _worker(study_file, storage_url, preexec_fn=None):
    return subprocess.run(
        [sys.executable, "-m", "surrogate", "worker", str(study_file), "--storage", storage_url],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=preexec_fn,
    )


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_line_exit_2(completed, *words):
    assert completed.returncode == 2, completed.stderr
    assert len(completed.stderr.strip().splitlines()) == 1, completed.stderr
    assert "Traceback" not in completed.stderr
    for word in words:
        assert word in completed.stderr


def test_read_only_sqlite_storage(study_file, tmp_path):
    database = tmp_path / "verify.db"
    _plan(study_file, f"sqlite:///{database}")
    before = _sha(database)
    completed = _worker(study_file, f"sqlite:///file:{database}?mode=ro&uri=true")
    _one_line_exit_2(completed, "read-only")
    assert _sha(database) == before


def test_read_only_postgresql_storage(study_file, postgres_url):
    _plan(study_file, postgres_url)
    read_only = f"{postgres_url}?options=-c%20default_transaction_read_only%3Don"
    _one_line_exit_2(_worker(study_file, read_only), "read-only")


def test_full_journal_storage(study_file, tmp_path):
    journal = tmp_path / "study.log"
    _plan(study_file, f"journal://{journal}")
    before, size = _sha(journal), journal.stat().st_size

    def no_room_to_grow():  # the file may not grow by one byte: a full disk for it
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

    _one_line_exit_2(_worker(study_file, str(journal), no_room_to_grow), "is full")
    assert _sha(journal) == before
