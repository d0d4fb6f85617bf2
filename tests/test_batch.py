"""Batch evaluation: workers, cache, resume, failed runs as rows."""

import multiprocessing
import os

import numpy as np
import pandas as pd
import pytest

from surrogate import PAPER_SPACE, SampleSet, make_design
from surrogate._pool import imap_unordered, one_blas_thread_within
from surrogate.solvers import _batch
from surrogate.solvers._batch import IN_PROCESS_RUNS, evaluate_design, solved
from tests.conftest import CountingSolve


@pytest.fixture
def design():
    return make_design("lhs", n=6, seed=11)


def test_cache_never_solves_a_point_twice(tmp_path, design):
    first, second = CountingSolve(), CountingSolve()
    a = evaluate_design(design, PAPER_SPACE, cache_dir=tmp_path, progress=False, solve=first)
    b = evaluate_design(design, PAPER_SPACE, cache_dir=tmp_path, progress=False, solve=second)
    assert first.calls == 6 and second.calls == 0
    pd.testing.assert_frame_equal(a.runs, b.runs)
    pd.testing.assert_frame_equal(a.curves, b.curves)
    assert b.meta["solver_calls"] == 0


def test_interrupted_batch_resumes_where_it_stopped(tmp_path, design):
    with pytest.raises(KeyboardInterrupt):
        evaluate_design(
            design,
            PAPER_SPACE,
            cache_dir=tmp_path,
            progress=False,
            solve=CountingSolve(stop_after=4),
        )
    resumed = CountingSolve()
    samples = evaluate_design(
        design, PAPER_SPACE, cache_dir=tmp_path, progress=False, solve=resumed
    )
    assert resumed.calls == 2 and len(samples.ok) == 6


@pytest.mark.parametrize("in_process_runs", [2, IN_PROCESS_RUNS])
def test_workers_give_the_same_results(tmp_path, design, monkeypatch, in_process_runs):
    """With ``jobs`` = 2 the six runs are solved in two processes (a batch at least
    ``IN_PROCESS_RUNS`` long) or in this one: the same runs, bit for bit, as ``jobs`` = 1."""
    monkeypatch.setattr(_batch, "IN_PROCESS_RUNS", in_process_runs)
    serial = evaluate_design(design, PAPER_SPACE, progress=False)
    parallel = evaluate_design(design, PAPER_SPACE, jobs=2, progress=False)
    pd.testing.assert_frame_equal(serial.runs, parallel.runs)


def test_a_failed_run_is_a_row_with_its_reason(tmp_path):
    design = make_design("lhs", n=3, seed=1)
    design.loc[1, "tcoat_mm"] = 0.7  # thicker than half the webbing: refused by the solver
    samples = evaluate_design(design, PAPER_SPACE, progress=False)
    assert list(samples.runs.status) == ["ok", "failed", "ok"]
    assert "tcoat_mm must be < thickness_mm/2" in samples.runs.reason.iloc[1]
    assert np.isnan(samples.runs.f60_n.iloc[1])
    assert set(samples.curves.run_id) == {1, 3}
    samples.write(tmp_path / "s.csv")
    again = SampleSet.read(tmp_path / "s.csv")
    assert again.n_failed == 1 and len(again.ok) == 2


def test_sample_set_round_trip(tmp_path, design):
    samples = evaluate_design(design, PAPER_SPACE, progress=False)
    samples.write(tmp_path / "s.csv")
    again = SampleSet.read(tmp_path / "s.csv")
    np.testing.assert_allclose(again.runs.f60_n, samples.runs.f60_n, rtol=1e-9)
    _angles, curves = again.curve_matrix()
    assert curves.shape == (6, 91)
    assert again.space == PAPER_SPACE
    assert again.meta["solver"] == "builtin" and again.meta["rig"]["width_mm"] == 38.0


def _pid(_: int) -> int:
    return os.getpid()


def test_a_pool_forks_no_more_processes_than_it_has_tasks():
    """A pool that forks starts every process at once: two tasks with ``jobs`` = 8 (a
    diagnosis's default, every CPU, on a verification's two runs) fork two, not eight."""
    seen = []
    for _, pid in imap_unordered(_pid, [0, 1], jobs=8):
        seen.append(pid)
        assert len(multiprocessing.active_children()) <= 2
    assert len(seen) == 2 and os.getpid() not in seen


def test_the_api_computes_with_one_blas_thread_and_gives_the_callers_back():
    """Inside an API function every BLAS library NumPy and SciPy loaded has one thread;
    after it, the caller's setting (two here) is back, also after an error."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from surrogate import simulate

    seen = []

    @one_blas_thread_within
    def probe(fail=False):
        seen.append(sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"))
        if fail:
            raise RuntimeError("inside")

    with threadpool_limits(2, user_api="blas"):
        probe()
        with pytest.raises(RuntimeError):
            probe(fail=True)
        after = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    assert len(seen[0]) >= 2 and seen == [[1] * len(seen[0])] * 2  # NumPy's and SciPy's
    assert after == [2] * len(after)
    assert simulate.__wrapped__ is not None and simulate.__name__ == "simulate"


def _where(inputs):
    """Where a run was solved: the process, and its BLAS threads."""
    from threadpoolctl import threadpool_info

    blas = [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]
    return {"pid": os.getpid(), "blas": max(blas)}


def test_a_short_batch_of_built_in_runs_is_solved_here_and_the_rest_in_processes(monkeypatch):
    """A built-in run takes milliseconds, a pool of processes tens of them to start: a batch of
    fewer than ``IN_PROCESS_RUNS`` built-in runs is solved in this process, with one BLAS
    thread as a child has; an external solver's runs (minutes each) and a long batch go to
    ``jobs`` processes."""
    from threadpoolctl import threadpool_limits

    builtin = [{"solver": "builtin", "run": i} for i in range(6)]
    external = [{"solver": "calculix", "run": i} for i in range(2)]
    with threadpool_limits(2, user_api="blas"):
        here = [result for _, result in solved(builtin, 2, _where)]
    assert {r["pid"] for r in here} == {os.getpid()} and {r["blas"] for r in here} == {1}
    assert os.getpid() not in {r["pid"] for _, r in solved(external, 2, _where)}
    monkeypatch.setattr(_batch, "IN_PROCESS_RUNS", 6)
    assert os.getpid() not in {r["pid"] for _, r in solved(builtin, 2, _where)}
