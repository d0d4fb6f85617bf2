"""``surrogate simulate`` as a user runs it: a real subprocess (its refusals in this
process, ``in_process``)."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

PAPER = ["--ecoat", "1.0", "--scoat", "0.2", "--tcoat", "0.012"]


def _run(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "surrogate", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=120,
    )


def test_table_and_features():
    result = _run("simulate", *PAPER)
    assert result.returncode == 0, result.stderr
    assert "F60 = 9.958 N" in result.stdout
    assert "theta_sat = 90 deg (not saturated" in result.stdout
    assert result.stdout.count("\n") > 10


def test_json_keys_and_values():
    result = _run("simulate", *PAPER, "--json")
    payload = json.loads(result.stdout)
    assert set(payload) == {
        "f60_n",
        "theta_sat_deg",
        "saturated",
        "angle_deg",
        "force_n",
        "force_perp_n",
    }
    assert payload["angle_deg"] == list(np.arange(91.0))
    assert payload["f60_n"] == pytest.approx(payload["force_n"][60])


def test_out_writes_the_curve_csv(tmp_path):
    out = tmp_path / "curve.csv"
    result = _run(
        "simulate",
        *PAPER,
        "--out",
        str(out),
        "--max-angle",
        "70",
        "--tension",
        "5",
        "--friction",
        "0.2",
    )
    assert result.returncode == 0, result.stderr
    table = pd.read_csv(out)
    assert list(table.columns) == ["angle_deg", "force_n", "force_perp_n"]
    assert len(table) == 71 and table.force_n.iloc[0] == 0.0


def test_rig_options_reach_the_solver():
    base = json.loads(_run("simulate", *PAPER, "--json").stdout)
    longer = json.loads(_run("simulate", *PAPER, "--json", "--bending-length", "15").stdout)
    coarse = json.loads(_run("simulate", *PAPER, "--json", "--element-size", "2.5").stdout)
    assert longer["f60_n"] < base["f60_n"]
    assert coarse["f60_n"] != base["f60_n"]


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--ecoat", "-1", "--scoat", "0.2", "--tcoat", "0.012"], "ecoat_gpa must be > 0"),
        (["--ecoat", "0", "--scoat", "0.2", "--tcoat", "0.012"], "ecoat_gpa must be > 0"),
        (["--ecoat", "1", "--scoat", "nan", "--tcoat", "0.012"], "finite"),
        (["--ecoat", "1", "--scoat", "0.2", "--tcoat", "0.6"], "thickness_mm/2 = 0.6 mm"),
        (
            ["--ecoat", "1", "--scoat", "0.2", "--tcoat", "0.7", "--thickness", "1.2"],
            "thickness_mm/2",
        ),
        ([*PAPER, "--bogus", "1"], "unrecognized arguments: --bogus"),
        ([*PAPER, "--friction", "-0.1"], "friction must be in"),
        ([*PAPER, "--max-angle", "0"], "max_angle_deg must be in"),
        (["--ecoat", "x", "--scoat", "0.2", "--tcoat", "0.012"], "invalid float value"),
        (["--scoat", "0.2", "--tcoat", "0.012"], "required: --ecoat"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, args, fragment, in_process):
    out = tmp_path / "curve.csv"
    code, stdout, stderr = in_process("simulate", *args, "--out", str(out))
    assert code == 2
    assert stdout == ""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert fragment in lines[0]
    assert "Traceback" not in stderr
    assert list(tmp_path.iterdir()) == []  # nothing written, not even a temp file
