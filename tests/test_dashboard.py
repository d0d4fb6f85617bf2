"""``surrogate dashboard``: optuna-dashboard on the study's storage, 127.0.0.1 only.

(The headless-browser check of the page is a separate, later test.)
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from surrogate.identify._loop import run
from tests.components import Dashboard

STUDIES = Path(__file__).resolve().parents[1] / "studies"
pytestmark = pytest.mark.slow


def test_dashboard_serves_the_verify_study_with_our_figure_and_note(tmp_path):
    study = tmp_path / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", study)
    result = run(study, progress=False, budget=8)
    with Dashboard(study) as dashboard:
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
    with Dashboard(study) as dashboard:
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
