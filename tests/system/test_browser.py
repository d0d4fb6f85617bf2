"""The dashboard of a finished study in a real browser (headless Chromium).

A short ``surrogate run`` with two local worker processes on a journal storage;
``surrogate dashboard`` serves it on 127.0.0.1; Chromium renders the JavaScript
app (``--dump-dom`` after a virtual-time budget) and the page must show every
verified trial, our plotly figure of the verified curves and our note.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

import optuna
import pytest

from surrogate.identify._loop import run
from surrogate.storage._storage import open_storage
from tests.components import Dashboard

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def _dump_dom(chromium: str, url: str) -> str:
    with tempfile.TemporaryDirectory(prefix="surrogate-chromium-") as profile:
        completed = subprocess.run(
            [
                chromium,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--disable-dev-shm-usage",
                f"--user-data-dir={profile}",
                "--virtual-time-budget=15000",
                "--dump-dom",
                url,
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert completed.returncode == 0, completed.stderr[-2000:]
    return completed.stdout


@pytest.fixture(scope="module")
def finished_study(tmp_path_factory):
    folder = tmp_path_factory.mktemp("browser")
    study = folder / "paper_coating.toml"
    shutil.copy(REPO / "studies" / "paper_coating.toml", study)
    storage = f"journal://{folder / 'verify.log'}"
    result = run(study, storage=storage, jobs=2, budget=8, progress=False)
    return study, storage, result


@pytest.fixture(scope="module")
def dashboard_url(finished_study):
    study, storage, _ = finished_study
    with Dashboard(study, storage) as dashboard:
        summaries = dashboard.studies()
        yield f"http://127.0.0.1:{dashboard.port}/dashboard/studies/{summaries[0]['study_id']}"


def test_the_run_with_two_local_workers_verified(finished_study):
    _, storage, result = finished_study
    assert result.status == "verified"
    study = optuna.load_study(study_name=result.study, storage=open_storage(storage))
    trials = study.get_trials(deepcopy=False)
    assert len(trials) == result.solver_calls
    hashes = [t.user_attrs["input_hash"] for t in trials]
    assert len(set(hashes)) == len(hashes)  # no run twice
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)


def test_chromium_shows_the_verified_trials(chromium, dashboard_url, finished_study):
    dom = _dump_dom(chromium, f"{dashboard_url}/trials")
    for number in range(finished_study[2].solver_calls):
        assert f"Trial {number}" in dom
    assert f"Trial {finished_study[2].solver_calls}" not in dom


def test_chromium_shows_our_figure_and_note(chromium, dashboard_url, finished_study):
    dom = _dump_dom(chromium, dashboard_url)
    assert "Verified full-solver curves against the target" in dom  # the plotly figure
    assert "(chosen)" in dom and "target F60 = 9.958 N" in dom
    note = _dump_dom(chromium, f"{dashboard_url}/note")
    assert "paper-coating: verified" in note and "Identifiability" in note
