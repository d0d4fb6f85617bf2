"""A database that cannot be reached for a while: workers wait for it (the storage
patience), the solve goes on, and no run is repeated; past the patience a worker stops
with one line saying so. Real PostgreSQL servers, stopped and started again."""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time

import optuna
import psycopg
import pytest
import sqlalchemy.exc
from optuna_dashboard import get_note

from surrogate.identify._doe import make_design
from surrogate.identify._verify import Verifier, open_verify_study
from surrogate.identify._worker import WorkerDispatcher, work
from surrogate.storage._storage import StorageError, open_storage, unreachable
from surrogate.study._spec import load_study
from tests.components import ComponentMissing, create_database, missing, postgres_control
from tests.components import throwaway_postgres as _throwaway_postgres
from tests.workers.fixed_cost import FixedCostSolve, events
from tests.workers.test_workers import _plan, _trials, _wait_for, _worker

TrialState = optuna.trial.TrialState


@pytest.fixture
def server():
    """A server of this test's own, so stopping it touches no other test."""
    try:
        with _throwaway_postgres() as url:
            yield url
    except ComponentMissing as error:
        missing(str(error))


def _finish(processes, timeout=120):
    """Return codes and stderr of each process, once it ends."""
    return [(p.communicate(timeout=timeout)[1], p.returncode) for p in processes]


@pytest.mark.slow
def test_workers_ride_out_a_database_restart_and_repeat_no_run(server, tmp_path, study_file):
    url = create_database(server, "outage")
    keys = _plan(study_file, url, 6)
    log = tmp_path / "solver.log"
    workers = [_worker(study_file, url, log, 2.0) for _ in range(2)]  # 1 s heartbeat, 3 s grace
    _wait_for(lambda: len([e for e, _, _ in events(log) if e == "start"]) >= 2)
    postgres_control(server, "stop")  # mid-solve: both runs take 2 s
    _wait_for(lambda: len([e for e, _, _ in events(log) if e == "done"]) >= 2)
    time.sleep(5)  # longer than the grace: every heartbeat is stale by now
    postgres_control(server, "start")
    for stderr, code in _finish(workers):
        assert code == 0, stderr
        assert "cannot be reached" in stderr and "is back after" in stderr
    trials = _trials(study_file, url)
    assert [t.state for t in trials] == [TrialState.COMPLETE] * len(keys)
    starts = collections.Counter(k for e, k, _ in events(log) if e == "start")
    assert starts == dict.fromkeys(keys, 1)


@pytest.mark.slow
def test_past_its_patience_a_worker_stops_with_one_line(server, tmp_path, study_file):
    url = create_database(server, "gone")
    _plan(study_file, url, 4)
    log = tmp_path / "solver.log"
    worker = _worker(study_file, url, log, 1.0, options=(1, "--storage-patience", 2))
    _wait_for(lambda: events(log))
    postgres_control(server, "stop")
    ((stderr, code),) = _finish([worker])
    assert code != 0
    last = stderr.strip().splitlines()[-1]
    assert "cannot use the storage" in last and "--storage-patience 2 s" in last, stderr


@pytest.mark.slow
def test_a_planner_queues_and_writes_through_a_database_restart(
    server, tmp_path, study_file, caplog
):
    """The planner's own writes ride out an outage as its waits do: the next phase's runs
    are queued once the database is back (each run solved once), and so is the result.
    Before, the queueing raised at once and the planner stopped between two phases."""
    url = create_database(server, "planner")
    spec = load_study(study_file)
    study = open_verify_study(spec, url, heartbeat_s=1)
    log = tmp_path / "solver.log"
    dispatcher = WorkerDispatcher(
        spec,
        url,
        jobs=1,
        heartbeat_s=1,
        storage_patience_s=60.0,
        solve=FixedCostSolve(log, 0.0),
        progress=False,
    )
    points = make_design("lhs", spec.space, n=4, seed=3).to_dict("records")
    with caplog.at_level(logging.WARNING, logger="surrogate"):
        with _down_for(server, 3.0):
            records = dispatcher(study, points, "plan")
        assert len(records) == 4 and all(r.ok for r in records.values())
        starts = collections.Counter(k for e, k, _ in events(log) if e == "start")
        assert starts == dict.fromkeys(records, 1)
        verifier = Verifier(spec, study, progress=False, dispatch=dispatcher)
        with _down_for(server, 3.0):
            verifier.publish({"status": "written"}, chosen_number=None, note="the note")
    stored = optuna.load_study(study_name=study.study_name, storage=open_storage(url))
    assert stored.user_attrs["result"] == {"status": "written"}
    assert get_note(stored) == "the note"
    said = [r.getMessage() for r in caplog.records]
    assert sum("cannot be reached" in m for m in said) == 2, said
    assert sum("is back after" in m for m in said) == 2, said


@pytest.mark.slow
def test_a_worker_started_by_a_planner_rides_out_an_outage_at_its_start(server, study_file):
    """A planner's local worker starts on a database the planner reached: an outage then
    is waited for. A worker started on its own on a database it cannot reach stops at
    once with one line, as the README says (a wrong address is not waited for)."""
    url = create_database(server, "start")
    _plan(study_file, url, 2)
    with _down_for(server, 3.0), pytest.raises(StorageError, match="cannot use the storage"):
        work(study_file, storage=url, idle_timeout_s=0.0, progress=False)
    log = study_file.parent / "solver.log"
    with _down_for(server, 3.0):
        result = work(
            study_file,
            storage=url,
            heartbeat_s=1,
            idle_timeout_s=0.0,
            storage_patience_s=60.0,
            storage_reached=True,
            solve=FixedCostSolve(log, 0.0),
            progress=False,
        )
    assert result.runs == result.ok == 2


@contextlib.contextmanager
def _down_for(server, seconds):
    """Stop ``server`` now and start it again after ``seconds``, while the block runs; an
    error of the start is raised here."""
    postgres_control(server, "stop")
    errors = []

    def start():
        try:
            postgres_control(server, "start")
        except Exception as error:  # raised in the test's thread, below
            errors.append(error)

    timer = threading.Timer(seconds, start)
    timer.start()
    try:
        yield
    finally:
        timer.join()
        if errors:
            raise errors[0]


def _chained(error):
    """``error`` as Optuna's RDB storage raises it: SQLAlchemy's error, from the driver's."""
    try:
        try:
            raise error
        except psycopg.Error as driver:
            raise sqlalchemy.exc.OperationalError("SELECT 1", {}, driver) from driver
    except sqlalchemy.exc.SQLAlchemyError as wrapped:
        try:
            raise optuna.exceptions.StorageInternalError("An exception is raised") from wrapped
        except optuna.exceptions.StorageInternalError as outer:
            return outer


@pytest.mark.parametrize(
    ("error", "expected"),
    [
        (psycopg.OperationalError("connection failed: Connection refused"), True),
        (psycopg.errors.AdminShutdown(), True),  # 57P01: the server is shutting down
        (psycopg.errors.ConnectionFailure(), True),  # 08006
        (psycopg.errors.DiskFull(), False),  # 53100: waiting will not free it
        (psycopg.errors.ReadOnlySqlTransaction(), False),
        (psycopg.errors.InvalidCatalogName(), False),  # no such database
    ],
)
def test_only_a_database_that_cannot_be_reached_is_waited_for(error, expected):
    assert unreachable(error) is expected
    assert unreachable(_chained(error)) is expected
    assert unreachable(OSError("disk full")) is False
