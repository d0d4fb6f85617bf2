"""``surrogate dashboard``: optuna-dashboard on the study's storage, 127.0.0.1 only.

(The headless-browser check of the page is a separate, later test.)
"""

import json
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from surrogate.identify._loop import run

STUDIES = Path(__file__).resolve().parents[1] / "studies"
pytestmark = pytest.mark.slow


def _free_port():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class _Dashboard:
    """``surrogate dashboard STUDY --port P`` in a subprocess, and its JSON API."""

    def __init__(self, study):
        self.port = _free_port()
        self.server = subprocess.Popen(
            [sys.executable, "-m", "surrogate", "dashboard", str(study), "--port", str(self.port)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.server.terminate()
        self.server.wait(timeout=10)

    def detail(self, study_name):
        """The dashboard's view of one study (trials, figures, note)."""
        summaries = None
        deadline = time.monotonic() + 180.0  # its start is imports: slow on a loaded machine
        while summaries is None and time.monotonic() < deadline:
            try:
                summaries = self._get("/api/studies")["study_summaries"]
            except OSError:
                if self.server.poll() is not None:  # it ended: no point waiting
                    break
                time.sleep(0.25)
        assert summaries, (
            f"the dashboard did not answer on 127.0.0.1 (exit code {self.server.poll()}; "
            f"{self.server.stderr.read() if self.server.poll() is not None else 'still running'})"
        )
        study_id = next(s["study_id"] for s in summaries if s["study_name"] == study_name)
        return self._get(f"/api/studies/{study_id}?after=0")

    def _get(self, path):
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}{path}", timeout=5) as r:
            return json.load(r)


def test_dashboard_serves_the_verify_study_with_our_figure_and_note(tmp_path):
    study = tmp_path / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", study)
    result = run(study, progress=False, budget=8)
    with _Dashboard(study) as dashboard:
        detail = dashboard.detail(result.study)
        assert len(detail["trials"]) == result.solver_calls
        assert [g["id"] for g in detail["plotly_graph_objects"]] == ["verified-curves"]
        assert result.status in detail["note"]["body"]
        bound = subprocess.run(["ss", "-ltn"], capture_output=True, text=True).stdout
        if bound:  # ss is there: the port listens on loopback only
            lines = [line for line in bound.splitlines() if f":{dashboard.port} " in line]
            assert lines and all("127.0.0.1:" in line for line in lines)


def test_dashboard_shows_what_a_calibration_determined(tmp_path):
    """The calibration study's note states the status, the misfit test and the intervals."""
    from surrogate import calibrate
    from surrogate.calibration._synthetic import calibration_sets, write_calibration_study

    case = next(c for c in calibration_sets() if c["name"] == "mid-n2")
    study = write_calibration_study(tmp_path, case)
    result = calibrate(study, progress=False)
    assert result.status == "converged", result.message
    with _Dashboard(study) as dashboard:
        detail = dashboard.detail(result.study)
    note = detail["note"]["body"]
    assert "## Calibration: converged" in note
    assert result.determination["statement"] in note
    assert f"F-test p = {result.misfit_p_value:.2g}" in note
    low = result.determination["combinations"]["bending_stiffness_nmm"]["low"]
    assert "| bending_stiffness_nmm | " in note and f"{low:.4g}" in note
    assert len(detail["trials"]) >= 2  # the verifications of both phases are its trials


def test_dashboard_without_a_storage_yet_is_refused(tmp_path):
    study = tmp_path / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", study)
    completed = subprocess.run(
        [sys.executable, "-m", "surrogate", "dashboard", str(study)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert completed.returncode == 2
    assert "run `surrogate run" in completed.stderr and len(completed.stderr.splitlines()) == 1
