"""The solver interface: registry, dispatch, cache keys, study-file settings, CLI."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from surrogate import InputDataError, Rig, simulate
from surrogate._cli import main
from surrogate.solvers import available_solvers, get_solver
from surrogate.solvers._batch import solve_inputs, solver_inputs
from surrogate.solvers._cache import input_hash
from surrogate.study._spec import load_study

POINT = {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012}


def test_registry_names_every_solver_and_refuses_others():
    assert available_solvers() == ("builtin", "calculix", "lsdyna")
    with pytest.raises(InputDataError, match="solver must be one of builtin, calculix, lsdyna"):
        get_solver("abaqus")


def test_builtin_through_the_interface_is_simulate():
    result = solve_inputs(solver_inputs(POINT, Rig()))
    curve = simulate(**POINT)
    assert result["status"] == "ok"
    np.testing.assert_array_equal(result["force_n"], curve.force_n)
    assert result["f60_n"] == curve.f60_n and result["theta_sat_deg"] == curve.theta_sat_deg


def test_settings_enter_the_hash_only_when_present():
    plain = solver_inputs(POINT, Rig())
    assert "solver_settings" not in plain  # builtin hashes are those of before issue 7
    coarse = solver_inputs(POINT, Rig(), solver="calculix", solver_settings={"mesh": "coarse"})
    fine = solver_inputs(POINT, Rig(), solver="calculix", solver_settings={"mesh": "fine"})
    assert coarse["solver_settings"] == {"mesh": "coarse"}
    assert len({input_hash(plain), input_hash(coarse), input_hash(fine)}) == 3
    assert coarse["solver_version"] != plain["solver_version"]  # the deck version keys ccx runs


def test_unknown_setting_is_a_failed_run_not_a_crash():
    inputs = solver_inputs(POINT, Rig(), solver="builtin", solver_settings={"mesh": "fine"})
    result = solve_inputs(inputs)
    assert result["status"] == "failed"
    assert "mesh is not a setting of the builtin solver" in result["reason"]


def _study(tmp_path: Path, solver: str) -> Path:
    path = tmp_path / "s.toml"
    path.write_text(f'[study]\nname = "s"\n[solver]\n{solver}\n[targets]\nf60_n = 10.0\n')
    return path


def test_study_solver_section(tmp_path):
    spec = load_study(_study(tmp_path, 'kind = "calculix"\nmesh = "fine"\ntimeout_s = 900'))
    assert spec.solver == "calculix"
    assert spec.solver_settings == {"mesh": "fine", "timeout_s": 900}
    (tmp_path / "deck.k").write_text("*KEYWORD\n*END\n")
    spec = load_study(_study(tmp_path, 'kind = "lsdyna"\ntemplate = "deck.k"'))
    assert spec.solver_settings["template"] == str((tmp_path / "deck.k").resolve())
    assert load_study(_study(tmp_path, 'kind = "builtin"')).solver_settings == {}


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ('kind = "calculix"\nmesh = "medium"', "mesh must be one of fine, coarse, got 'medium'"),
        ('kind = "calculix"\ntimeout_s = -1', "timeout_s must be a number of seconds > 0"),
        ('kind = "calculix"\nmeshh = "fine"', "meshh is not a setting of the calculix solver"),
        ('kind = "lsdyna"', "template (the LS-DYNA keyword deck) is required"),
        ('kind = "abaqus"', "kind must be one of builtin, calculix, lsdyna"),
    ],
)
def test_bad_solver_section_is_one_line_exit_2(tmp_path, capsys, section, message):
    path = _study(tmp_path, section)
    with pytest.raises(SystemExit) as exit_info:
        main(["run", str(path)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]  # nothing written


def test_cli_simulate_rejects_a_bad_solver_option():
    done = subprocess.run(
        [sys.executable, "-m", "surrogate", "simulate", "--ecoat", "1", "--scoat", "0.2",
         "--tcoat", "0.012", "--solver", "calculix", "--solver-option", "mesh"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2
    assert "expected KEY=VALUE" in done.stderr and done.stderr.count("\n") == 1


def test_a_runs_identity_leaves_out_how_to_run_but_not_what():
    def key(**settings):
        return input_hash(solver_inputs(POINT, Rig(), solver="calculix", solver_settings=settings))

    coarse = key(mesh="coarse")
    # the program, its timeout, threads and work folders do not change the result
    assert key(mesh="coarse", timeout_s=60, threads=2, workdir_root="/elsewhere") == coarse
    assert key(mesh="coarse", command=["/opt/ccx/bin/ccx"], keep_workdir=True) == coarse
    assert key(mesh="fine") != coarse  # the mesh does
    assert input_hash(solver_inputs(POINT, Rig(), solver="calculix")) != coarse


def test_the_same_study_in_another_folder_is_the_same_plan(tmp_path):
    from surrogate.identify._verify import as_planned, plan_attributes

    text = (Path(__file__).parents[2] / "studies" / "paper_coating_calculix.toml").read_text()
    here, there = tmp_path / "a", tmp_path / "b"
    for folder, timeout in ((here, 1800), (there, 60)):
        folder.mkdir()
        settings = f'timeout_s = {timeout}\nworkdir_root = "work"'  # resolved per folder
        (folder / "s.toml").write_text(text.replace("timeout_s = 1800", settings))
    planned, joining = load_study(here / "s.toml"), load_study(there / "s.toml")
    assert planned.solver_settings["workdir_root"] != joining.solver_settings["workdir_root"]
    as_planned(joining, plan_attributes(planned))  # accepted: the runs are the same
    finer = load_study(there / "s.toml")
    finer.solver_settings["mesh"] = "fine"
    with pytest.raises(InputDataError, match=r"\[solver\] differs .*mesh: 'coarse' planned"):
        as_planned(finer, plan_attributes(planned))
