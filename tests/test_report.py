"""``surrogate report``: one self-contained HTML page of a study, opened in a real browser.

A short ``surrogate run`` on a copy of the paper study, then ``surrogate report``
through the command line; headless Chromium opens the file with networking
disabled, and the page must log nothing to the console (Chromium logs every console
level alike, ``INFO:CONSOLE``, so the test asks for no console line at all), render
its plotly figure, and not be blank. A calibration on synthetic curves shows its
parameters with their 95 % intervals and the residual tables. Bad input is one
line and exit code 2, with nothing written.
"""

from __future__ import annotations

import html
import shutil
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import optuna
import pandas as pd
import pytest

import surrogate
from surrogate._cli import main
from surrogate.calibration import DiagnosisResult
from surrogate.calibration._compare import comparison
from surrogate.calibration._determination import parameter_interval_text
from surrogate.calibration._synthetic import synthetic_measurements
from surrogate.identify._loop import run
from surrogate.identify._verify import Verifier, open_verify_study
from surrogate.study._spec import load_study
from tests.components import INSTALL, chromium_binary, missing
from tests.studies import write_study

STUDIES = Path(__file__).resolve().parents[1] / "studies"


def _chromium_opens(page: Path, screenshot: Path) -> tuple[str, str]:
    """(the DOM after the page's JavaScript ran, Chromium's log) with no network."""
    chromium = chromium_binary()
    if chromium is None:
        missing(f"Chromium not found; {INSTALL}")
    with tempfile.TemporaryDirectory(prefix="surrogate-chromium-") as profile:
        completed = subprocess.run(
            [
                chromium,
                *("--headless", "--no-sandbox", "--disable-gpu", "--no-first-run"),
                *("--disable-background-networking", "--disable-component-update"),
                *("--disable-sync", "--disable-dev-shm-usage", f"--user-data-dir={profile}"),
                # no network: every host unresolvable, every proxy connection refused
                "--host-resolver-rules=MAP * ~NOTFOUND",
                "--proxy-server=127.0.0.1:9",
                *("--enable-logging=stderr", "--v=0"),
                *("--virtual-time-budget=10000", "--window-size=1200,3000"),
                f"--screenshot={screenshot}",
                "--dump-dom",
                page.as_uri(),
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert completed.returncode == 0, completed.stderr[-2000:]
    return completed.stdout, completed.stderr


def _not_blank(png: Path) -> tuple[float, int]:
    """(share of pixels that are not white, distinct colours) of a screenshot."""
    import matplotlib.image

    rgb = matplotlib.image.imread(png)[..., :3]
    colours = np.unique((rgb * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    return float(np.mean(rgb.min(axis=2) < 0.95)), len(colours)


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """A copy of the paper study after a short ``surrogate run`` (150 surrogate trials an
    iteration instead of 300, to keep the test short; it verifies in 7 runs)."""
    folder = tmp_path_factory.mktemp("report")
    study = folder / "paper_coating.toml"
    text = (STUDIES / "paper_coating.toml").read_text()
    study.write_text(text.replace("surrogate_trials = 300", "surrogate_trials = 150"))
    return study, run(study, budget=10, progress=False)


@pytest.mark.slow
def test_the_report_of_a_run_opens_offline_in_chromium(ran, tmp_path):
    study, result = ran
    page = tmp_path / "signed-off.html"
    completed = subprocess.run(
        [sys.executable, "-m", "surrogate", "report", str(study), "--output", str(page)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert completed.returncode == 0, completed.stderr
    assert f"written to {page}" in completed.stdout
    text = page.read_text()
    # self-contained: plotly's JavaScript embedded once, nothing loaded from elsewhere
    assert text.count("plotly.js v") == 1 and "<script src=" not in text
    chosen = result.verified
    assert result.status == "verified"
    for shown in (
        str(study.resolve()),
        "rod-2",  # the solver's version, with its verification figures
        "0.083 %",
        "bending_length_mm",
        f"{chosen['ecoat_gpa']:.4g}",
        f"{chosen['f60_n']:.4g}",
        result.identifiability["statement"],
        surrogate.export(study).text,  # the LS-DYNA snippet
        "This study has no measured curves",  # the calibration sections say why they are empty
    ):
        assert html.escape(shown) in text, shown

    dom, log = _chromium_opens(page, tmp_path / "page.png")
    console = [line for line in log.splitlines() if "CONSOLE" in line or "Uncaught" in line]
    assert console == []
    assert dom.count('class="main-svg"') >= 1 and "js-plotly-plot" in dom
    assert "Verified full-solver curves against the target" in dom  # drawn by plotly.js
    inked, colours = _not_blank(tmp_path / "page.png")
    assert inked > 0.05 and colours > 100, (inked, colours)


@pytest.mark.slow
def test_the_report_is_listed_once_in_the_dashboard(ran):
    """The page is an optuna artifact of the verify study; made again, it replaces itself."""
    study, result = ran
    first = surrogate.report(study)
    second = surrogate.report(study)
    assert first.attached == second.attached == [result.study]
    verify = optuna.load_study(study_name=result.study, storage=result.storage)
    metas = optuna.artifacts.get_all_artifact_meta(verify)
    metas = [m for m in metas if m.filename == "paper-coating-report.html"]
    assert len(metas) == 1
    stored = study.parent / "paper-coating-artifacts" / metas[0].artifact_id
    assert stored.read_bytes() == Path(second.output).read_bytes()


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A study of two replicate tests on synthetic curves, calibrated (converged)."""
    folder = tmp_path_factory.mktemp("calibrated")
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    tests = [
        {"test_id": "a1", "tension_n": 0.0, "temperature_c": 21.0},
        {"test_id": "a2", "tension_n": 0.0, "temperature_c": 24.0},
    ]
    study = write_study(
        folder,
        synthetic_measurements(tests, coating=truth, noise_n=0.05, seed=1),
        """
        [study]
        name = "cal"
        [measurements]
        file = "tests.csv"
        [budget]
        calibration_solver_calls = 30
        surrogate_trials = 50
        """,
        ranges=True,
    )
    fitted = surrogate.calibrate(study, progress=False)
    assert fitted.status == "converged", fitted.message
    return study, fitted


@pytest.mark.slow
def test_the_report_of_a_calibration_shows_intervals_and_residuals(calibrated, capsys):
    study, fitted = calibrated
    assert main(["report", str(study)]) == 0
    assert "written to" in capsys.readouterr().out
    text = (study.parent / "cal-report.html").read_text()
    determination = fitted.determination
    for name, value in fitted.params.items():
        span = html.escape(parameter_interval_text(name, determination))
        assert f"<td>{name}</td><td>{value:.4g}</td><td>{span}" in text, span
    stiffness = determination["combinations"]["bending_stiffness_nmm"]
    assert f"<td>bending_stiffness_nmm</td><td>{stiffness['value']:.4g}</td>" in text
    assert html.escape(determination["statement"]) in text
    assert fitted.misfit in text and "RMSE / noise" in text
    # the residual by test (with its conditions and covariates), by band, by column
    compared = surrogate.compare(study, plots=False, progress=False)
    for row in compared.tests:
        cells = [row["test_id"], "0", f"{row['temperature_c']:g}", f"{row['rmse_n']:.4g}"]
        assert "<td>" + "</td><td>".join(cells) + f"</td><td>{row['bias_n']:.4g}</td>" in text
    for band in compared.bands:
        assert f"<td>{band['band']}</td><td>{band['rmse_n']:.4g}</td>" in text
    assert "Measured and model curves" in text  # the figure of curves against measurements
    assert "No diagnosis in this storage yet: run `surrogate diagnose" in text
    assert "does not apply" in text  # no F60 target: no identification


@pytest.mark.slow
def test_the_report_shows_the_stored_diagnosis(calibrated):
    """What `surrogate diagnose` stores on the calibration study (its --json record)."""
    study, fitted = calibrated
    found = DiagnosisResult(
        **{**dict.fromkeys(DiagnosisResult.__dataclass_fields__), "where": [], "follows": []},
    )
    found = replace(
        found,
        verdict="no systematic misfit: no effect needed",
        ranking=[{"effect": "tension", "rmse_n": 0.044, "heldout_rmse_n": 0.045, "delta_bic": 9.1}],
        tied_with=["rate"],
    )
    calibration = optuna.load_study(study_name=fitted.study, storage=fitted.storage)
    calibration.set_user_attr("diagnosis", found.to_json())
    assert "diagnosis" in surrogate.report(study).shown
    text = (study.parent / "cal-report.html").read_text()
    assert "Verdict on model base: no systematic misfit: no effect needed" in text
    assert "<td>tension</td><td>0.044</td><td>0.045</td><td>9.1</td>" in text
    assert "cannot tell them apart): rate" in text


@pytest.mark.slow
def test_the_report_shows_the_stored_next_test(calibrated, tmp_path):
    """What `surrogate next-test` stores on the calibration study: its message (with the
    effects the data cannot test) and its ranked tests in the goal's words; the
    section's place-holder before it ran, and a warning once the data changed since."""
    study, _ = calibrated
    before = tmp_path / "before.html"
    assert "next_test" not in surrogate.report(study, output=before).shown
    assert "No recommended test in this storage yet: run `surrogate next-test" in before.read_text()
    copy = tmp_path / "study"
    shutil.copytree(study.parent, copy)
    designed = copy / study.name
    designed.write_text(
        designed.read_text() + "\n[design]\nbending_length_mm = { low = 5.0, high = 17.5 }\n"
    )
    found = surrogate.next_test(designed, plots=False, progress=False)
    assert found.recommended and found.untestable
    page = tmp_path / "after.html"
    assert "next_test" in surrogate.report(designed, output=page).shown
    text = page.read_text()
    assert html.escape(found.message) in text
    assert all(html.escape(entry["reason"]) in text for entry in found.untestable)
    best, goal = found.recommended[0], found.goal
    conditions = ", ".join(f"{k} {v:g}" for k, v in best["conditions"].items())
    precision = best["predicted"][goal]["precision"]
    cells = [html.escape(conditions), str(best["replicates"]), html.escape(precision)]
    assert "<td>1</td><td>" + "</td><td>".join(cells) + "</td>" in text
    assert f"{found.candidates} candidate tests)" in text
    assert "Made on other measurements" not in text
    # the lab measures another test and calibrates again: the recommendation is stale
    table = pd.read_csv(copy / "tests.csv")
    extra = table[table["test_id"] == table["test_id"].iloc[0]].assign(test_id="again")
    pd.concat([table, extra]).to_csv(copy / "tests.csv", index=False)
    surrogate.calibrate(designed, progress=False)
    stale = tmp_path / "stale.html"
    surrogate.report(designed, output=stale)
    assert "Made on other measurements than the calibration shown" in stale.read_text()


@pytest.mark.slow
def test_external_solver_curves_are_taken_from_the_cache_only(calibrated, tmp_path):
    """A reader must not start an hour-long run: ``solve=False`` uses the result cache."""
    study, fitted = calibrated
    assert comparison(study, solve=False).result.rmse_n == pytest.approx(fitted.rmse_n)
    for name in ("study.toml", "tests.csv", "cal.db"):  # the same study without its cache
        shutil.copy(study.parent / name, tmp_path / name)
    with pytest.raises(surrogate.InputDataError, match="not in the result cache"):
        comparison(tmp_path / "study.toml", solve=False)


def _verified(folder: Path) -> Path:
    """A study with two verified runs in its storage (as `surrogate run` records them)."""
    study = folder / "coat.toml"
    target = surrogate.simulate(1.0, 0.2, 0.012).f60_n
    study.write_text(f'[study]\nname = "coat"\n[targets]\nf60_n = {target!r}\n')
    spec = load_study(study)
    verifier = Verifier(
        spec, open_verify_study(spec, spec.default_storage(), heartbeat_s=None), progress=False
    )
    verifier.verify(np.array([[2.0, 0.1, 0.03], [1.0, 0.2, 0.012]]), phase="test")
    return study


def _refused(args, capsys) -> str:
    with pytest.raises(SystemExit) as exit_info:
        main(["report", *map(str, args)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


def test_nothing_run_yet_is_one_line_and_nothing_is_written(tmp_path, capsys):
    study = tmp_path / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", study)
    assert "no storage at" in _refused([study], capsys)
    assert [p.name for p in tmp_path.iterdir()] == ["paper_coating.toml"]  # none is created
    optuna.create_study(study_name="other/verify", storage=f"sqlite:///{tmp_path}/paper-coating.db")
    capsys.readouterr()
    err = _refused([study], capsys)  # a storage with nothing of this study
    assert "nothing of study 'paper-coating'" in err and "run `surrogate run" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paper-coating.db", "paper_coating.toml"]


def test_an_output_folder_that_cannot_be_written_is_refused(tmp_path, capsys):
    study = _verified(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert "does not exist" in _refused([study, "--output", tmp_path / "no" / "r.html"], capsys)
    assert "is a file; choose another" in _refused([study, "--output", study / "r.html"], capsys)
    assert "is a folder" in _refused([study, "--output", tmp_path], capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_without_plotly_the_report_says_how_to_get_it(tmp_path, capsys, monkeypatch):
    study = _verified(tmp_path)
    monkeypatch.setitem(sys.modules, "plotly", None)  # import plotly raises ImportError
    assert "pip install 'webbing-surrogate[plots]'" in _refused([study], capsys)
    assert not (tmp_path / "coat-report.html").exists()


def test_the_api_report_is_the_function_whichever_import_came_first():
    """``surrogate.report`` stays the function after the CLI (or anyone) imported the
    package that holds it: the package is ``surrogate.reporting``. Named ``report``,
    its import set ``surrogate.report`` to the package, and the suite's
    ``surrogate.report(study)`` failed ("'module' object is not callable") wherever an
    in-process ``surrogate report`` command had run first in the same process."""
    code = (
        "import surrogate, surrogate.reporting\n"
        "assert surrogate.report is surrogate.reporting.report, surrogate.report\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
