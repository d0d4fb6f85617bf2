"""``surrogate doe | fit | predict`` end to end, and their bad input."""

import hashlib
import json
import signal
import subprocess
import sys

import pandas as pd
import pytest

pytestmark = pytest.mark.slow  # calibrations and diagnoses: CI runs them, the dev loop not


def _run(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "surrogate", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
    )


def _snapshot(folder):
    return {
        p.relative_to(folder): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    result = _run(
        "doe",
        "--design",
        "lhs",
        "--n",
        "12",
        "--seed",
        "2",
        "--run",
        "--jobs",
        "2",
        "--out",
        "samples.csv",
        "--json",
        cwd=folder,
    )
    assert result.returncode == 0, result.stderr
    payload = json.loads(result.stdout)
    assert payload["n_ok"] == 12 and payload["solver_calls"] == 12
    return folder


def test_doe_run_again_uses_the_cache(workdir):
    again = json.loads(
        _run(
            "doe",
            "--design",
            "lhs",
            "--n",
            "12",
            "--seed",
            "2",
            "--run",
            "--out",
            "samples2.csv",
            "--cache",
            ".solver-cache",
            "--json",
            cwd=workdir,
        ).stdout
    )
    assert again["solver_calls"] == 0 and again["cached"] == 12


def test_paper_design_without_run(workdir):
    payload = json.loads(
        _run("doe", "--design", "paper", "--out", "paper.csv", "--json", cwd=workdir).stdout
    )
    assert payload["n_points"] == 64
    assert len(pd.read_csv(workdir / "paper.csv")) == 64


@pytest.fixture(scope="module")
def fitted(workdir):
    """``surrogate fit`` of the samples, once for the module: its output, and
    ``model.json`` in ``workdir``."""
    result = _run("fit", "samples.csv", "--out", "model.json", cwd=workdir)
    assert result.returncode == 0, result.stderr  # else every test using it says why
    return result


def test_fit_prints_cv_and_json(workdir, fitted):
    result = fitted
    assert result.returncode == 0, result.stderr
    assert "LOO median rel err" in result.stdout and "f60_n" in result.stdout
    payload = json.loads(_run("fit", "samples.csv", "--json", cwd=workdir).stdout)
    for output in ("f60_n", "theta_sat_deg"):
        assert set(payload[output]) == {"loo_median_rel_err", "loo_mae", "coverage95"}


def test_predict_adds_columns(workdir, fitted):
    _run("doe", "--design", "sobol", "--n", "4", "--seed", "9", "--out", "points.csv", cwd=workdir)
    result = _run("predict", "model.json", "points.csv", "--out", "pred.csv", cwd=workdir)
    assert result.returncode == 0, result.stderr
    table = pd.read_csv(workdir / "pred.csv")
    for column in ("f60_n", "f60_n_std", "theta_sat_deg", "theta_sat_deg_std"):
        assert column in table and table[column].notna().all()


BAD_POINTS = {
    "nan": "case_id,ecoat_gpa,scoat_gpa,tcoat_mm\na,1.0,nan,0.02\n",
    "negative": "case_id,ecoat_gpa,scoat_gpa,tcoat_mm\na,1.0,0.2,-0.02\n",
    "missing": "case_id,ecoat_gpa,scoat_gpa\na,1.0,0.2\n",
    "text": "case_id,ecoat_gpa,scoat_gpa,tcoat_mm\na,1.0,abc,0.02\n",
    "empty": "case_id,ecoat_gpa,scoat_gpa,tcoat_mm\n",
}


@pytest.mark.parametrize("kind", sorted(BAD_POINTS))
def test_bad_points_file_is_refused_and_nothing_written(
    workdir, fitted, kind, tmp_path, in_process
):
    bad = tmp_path / "bad.csv"
    bad.write_text(BAD_POINTS[kind])
    (tmp_path / "model.json").write_bytes((workdir / "model.json").read_bytes())
    before = _snapshot(tmp_path)
    code, _, err = in_process("predict", "model.json", "bad.csv", "--out", "pred.csv", cwd=tmp_path)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert _snapshot(tmp_path) == before


BAD_SAMPLES = {
    "nan-parameter": lambda t: t.assign(ecoat_gpa=[float("nan"), *list(t.ecoat_gpa[1:])]),
    "negative-parameter": lambda t: t.assign(tcoat_mm=[-0.01, *list(t.tcoat_mm[1:])]),
    "missing-column": lambda t: t.drop(columns=["f60_n"]),
    "bad-status": lambda t: t.assign(status=["maybe", *list(t.status[1:])]),
}


@pytest.mark.parametrize("kind", sorted(BAD_SAMPLES))
def test_bad_sample_file_is_refused_and_nothing_written(workdir, kind, tmp_path, in_process):
    table = BAD_SAMPLES[kind](pd.read_csv(workdir / "samples.csv"))
    table.to_csv(tmp_path / "samples.csv", index=False)
    before = _snapshot(tmp_path)
    code, out, err = in_process("fit", "samples.csv", "--out", "model.json", cwd=tmp_path)
    assert code == 2, out
    assert len(err.strip().splitlines()) == 1, err
    assert _snapshot(tmp_path) == before


def test_bad_design_request_writes_nothing(tmp_path, in_process):
    for args in (
        ["--design", "lhs", "--n", "0"],
        ["--design", "grid"],
        ["--design", "lhs", "--jobs", "0", "--run"],
    ):
        code, _, err = in_process("doe", *args, "--out", "x.csv", cwd=tmp_path)
        assert code == 2, (args, err)
        assert len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


BAD_DESIGNS = {
    **BAD_POINTS,
    "out-of-range": "case_id,ecoat_gpa,scoat_gpa,tcoat_mm\na,9.0,0.2,0.02\n",
}


@pytest.mark.parametrize("kind", sorted(BAD_DESIGNS))
def test_bad_design_file_is_refused_and_nothing_written(kind, tmp_path, in_process):
    (tmp_path / "design.csv").write_text(BAD_DESIGNS[kind])
    before = _snapshot(tmp_path)
    code, _, err = in_process(
        "doe", "--from", "design.csv", "--run", "--out", "samples.csv", cwd=tmp_path
    )
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert _snapshot(tmp_path) == before  # no sample set, no cache entry


def test_design_file_of_ones_own_runs(tmp_path):
    (tmp_path / "design.csv").write_text(
        "case_id,ecoat_gpa,scoat_gpa,tcoat_mm\nmine-1,1.0,0.2,0.012\nmine-2,2.0,0.1,0.05\n"
    )
    result = _run(
        "doe", "--from", "design.csv", "--run", "--out", "samples.csv", "--json", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["design"] == "file"
    table = pd.read_csv(tmp_path / "samples.csv")
    assert list(table.case_id) == ["mine-1", "mine-2"]
    assert table.f60_n.iloc[0] == pytest.approx(9.958, abs=1e-3)


_STOPPED_AND_SIGNALLED_AGAIN = """
import atexit, os, signal, sys, time
from surrogate import _cli

def handler(args):
    raise KeyboardInterrupt  # the command's Ctrl-C

@atexit.register
def again():  # what SIGINT does to the process on its way out
    print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN, flush=True)
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.2)

_cli._COMMANDS = [(lambda commands: commands.add_parser("stop"), handler)]
sys.argv = ["surrogate", "stop"]
sys.exit(_cli.main())
"""


def test_a_stopped_command_ignores_a_second_ctrl_c_on_its_way_out():
    """The ``surrogate`` command stopped by Ctrl-C says so in one line and exits 130; from
    then on SIGINT is ignored, so another one as it exits (the user's, or a swallowed one
    sent again) cannot end it with another status."""
    done = subprocess.run(
        [sys.executable, "-c", _STOPPED_AND_SIGNALLED_AGAIN],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == "surrogate: interrupted (Ctrl-C)", done.stderr
    assert done.stdout.strip() == "True"
