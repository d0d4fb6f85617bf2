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

from surrogate._run import run

STUDIES = Path(__file__).resolve().parents[1] / "studies"
pytestmark = pytest.mark.slow


def _free_port():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_dashboard_serves_the_verify_study_with_our_figure_and_note(tmp_path):
    study = tmp_path / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", study)
    result = run(study, progress=False, budget=8)
    port = _free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "surrogate", "dashboard", str(study), "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        summaries = None
        for _ in range(60):
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/studies", timeout=2) as r:
                    summaries = json.load(r)["study_summaries"]
                break
            except OSError:
                time.sleep(0.25)
        assert summaries, "the dashboard did not answer on 127.0.0.1"
        study_id = next(s["study_id"] for s in summaries if s["study_name"] == result.study)
        with urllib.request.urlopen(
            f"http://127.0.0.1:{port}/api/studies/{study_id}?after=0", timeout=5
        ) as response:
            detail = json.load(response)
        assert len(detail["trials"]) == result.solver_calls
        assert [g["id"] for g in detail["plotly_graph_objects"]] == ["verified-curves"]
        assert result.status in detail["note"]["body"]
        bound = subprocess.run(["ss", "-ltn"], capture_output=True, text=True).stdout
        if bound:  # ss is there: the port listens on loopback only
            lines = [line for line in bound.splitlines() if f":{port} " in line]
            assert lines and all("127.0.0.1:" in line for line in lines)
    finally:
        server.terminate()
        server.wait(timeout=10)


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
