"""LS-DYNA adapter: deck filling in fixed 10-character fields, the rcforc and
nodout parsers on files in the documented layouts, and the run path with a
stand-in executable (LS-DYNA itself is not available here)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from surrogate import InputDataError, Rig, simulate
from surrogate.effects import ModelState
from surrogate.solvers import (
    LsDynaSolver,
    coating_parameters,
    fill_parameters,
    fill_seatbelt_card,
    parse_nodout_rotation,
    parse_rcforc,
)
from surrogate.solvers._batch import solve_inputs, solver_inputs
from surrogate.solvers._lsdyna import format_real

FIXTURES = Path(__file__).parent / "fixtures"
TEMPLATE = FIXTURES / "bending_template.k"
VALUES = {"ECOAT": 1183.25, "SCOAT": 372.9, "TCOAT": 0.01017}


def _fields(line: str) -> list[str]:
    return [line[k : k + 10] for k in range(0, 80, 10)]


def test_format_real_fits_ten_characters_and_keeps_the_value():
    for value in (1183.25, 0.01017, 372.9, 1.0e-7, 2.5e9, -0.5, 123456789.0):
        text = format_real(value)
        assert len(text) == 10
        assert float(text) == pytest.approx(value, rel=1e-4)  # ≤ 7 significant digits


def test_parameter_values_replace_the_template_fields_in_place():
    deck = fill_parameters(TEMPLATE.read_text(), VALUES)
    lines = deck.splitlines()
    card = lines[lines.index("*PARAMETER") + 2]
    fields = _fields(card.ljust(80))
    assert [f[0] for f in fields[0::2]] == ["R"] * 4
    assert [f[1:].strip() for f in fields[0::2]] == ["ECOAT", "SCOAT", "TCOAT", "MUPROBE"]
    assert [float(f) for f in fields[1::2]] == pytest.approx([1183.25, 372.9, 0.01017, 0.1])
    assert deck.count("*PARAMETER") == 1  # nothing appended: every name was there
    assert "&ECOAT" in deck  # the material card still refers to the parameter


def test_missing_parameters_get_a_new_block_after_keyword():
    deck = fill_parameters("*KEYWORD\n*END\n", {**VALUES, "KE": 0.02})
    lines = deck.splitlines()
    assert lines[:2] == ["*KEYWORD", "*PARAMETER"]
    cards = [line for line in lines[2:4] if not line.startswith("$")]
    fields = _fields(cards[0].ljust(80))
    assert fields[0].split() == ["R", "ECOAT"] and float(fields[1]) == 1183.25
    assert fields[6].split() == ["R", "KE"] and float(fields[7]) == 0.02
    with pytest.raises(InputDataError, match="1–9 characters"):
        fill_parameters("*KEYWORD\n", {"TOOLONGNAME": 1.0})
    with pytest.raises(InputDataError, match=r"\*KEYWORD"):
        fill_parameters("*END\n", VALUES)


def test_seatbelt_card3_gets_ecoat_tcoat_scoat_in_fields_3_4_5():
    deck = fill_seatbelt_card(TEMPLATE.read_text(), VALUES)
    lines = deck.splitlines()
    card3 = lines[lines.index("$#  p1doff      form     ecoat     tcoat     scoat") + 1]
    fields = _fields(card3.ljust(80))
    assert fields[0].strip() == "0" and fields[1].strip() == "14"  # P1DOFF, FORM kept
    # TCOAT before SCOAT on this card (unlike *MAT_FABRIC)
    assert [float(f) for f in fields[2:5]] == pytest.approx([1183.25, 0.01017, 372.9])
    assert len(card3) <= 80
    with pytest.raises(InputDataError, match="no \\*MAT_SEATBELT_2D"):
        fill_seatbelt_card("*KEYWORD\n*END\n", VALUES)


def test_coating_parameters_in_deck_units():
    state = ModelState(1000.0, 200.0, 0.012, Rig(), hardening_ratio=0.05)
    assert coating_parameters(state) == pytest.approx(
        {"ECOAT": 1000.0, "SCOAT": 200.0, "TCOAT": 0.012, "HCOAT": 50.0}
    )
    kn_ms = coating_parameters(state, units="mm-kg-ms")  # GPa
    assert kn_ms["ECOAT"] == pytest.approx(1.0) and kn_ms["SCOAT"] == pytest.approx(0.2)
    si = coating_parameters(state, units="m-kg-s")  # Pa, m
    assert si["ECOAT"] == pytest.approx(1e9) and si["TCOAT"] == pytest.approx(1.2e-5)


def test_rcforc_parser_reads_one_interface_side():
    text = (FIXTURES / "rcforc_probe.txt").read_text()
    master = parse_rcforc(text)
    np.testing.assert_allclose(master.time, [0.0, 30.0, 60.0, 90.0])
    np.testing.assert_allclose(master.force[2], [-2.8, 0.0, -9.4])
    slave = parse_rcforc(text, side="slave")
    np.testing.assert_allclose(slave.force, -master.force)
    other = parse_rcforc(text, interface=2)
    np.testing.assert_allclose(other.force[:, 0], 7.0)
    with pytest.raises(RuntimeError, match="no master lines of interface 3"):
        parse_rcforc(text, interface=3)


def test_nodout_parser_reads_the_rotation_block_only():
    text = (FIXTURES / "nodout_clamp.txt").read_text()
    times, angles = parse_nodout_rotation(text, 500)
    np.testing.assert_allclose(times, [0.0, 45.0])
    np.testing.assert_allclose(angles, [0.0, -0.7854])  # y-rot, not the y-disp column
    _, x_rot = parse_nodout_rotation(text, 501, axis=1)
    np.testing.assert_allclose(x_rot, [0.0])


# -- the run path, with a stand-in executable -------------------------------------------------
POINT = {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012}


def _settings(tmp_path: Path, **extra):
    return {
        "template": str(TEMPLATE),
        "command": [sys.executable, str(FIXTURES / "fake_lsdyna.py")],
        "workdir_root": str(tmp_path / "work"),
        "timeout_s": 120,
        **extra,
    }


@pytest.mark.parametrize(
    "extra", [{}, {"fill": "seatbelt_card"}, {"rotation_node": 900001}], ids=str
)
def test_run_path_with_a_stand_in_executable(tmp_path, extra):
    """The stand-in (tests/solvers/fixtures/fake_lsdyna.py, NOT LS-DYNA) runs the
    built-in solver on the values it reads from the filled deck and writes
    rcforc/nodout; the adapter must give back the built-in curve."""
    inputs = solver_inputs(
        POINT, Rig(), solver="lsdyna", solver_settings=_settings(tmp_path, **extra)
    )
    result = solve_inputs(inputs)
    assert result["status"] == "ok", result["reason"]
    reference = simulate(**POINT)
    # rcforc prints 6 significant digits, nodout's rotations 5 (E11.4): the
    # resampling to whole degrees is exact to about that
    np.testing.assert_allclose(result["force_n"], reference.force_n, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(result["force_perp_n"], reference.force_perp_n, atol=1e-3)
    assert result["f60_n"] == pytest.approx(reference.f60_n, rel=1e-4)
    assert list((tmp_path / "work").iterdir()) == []  # work dir removed


def test_a_failed_lsdyna_run_is_a_failed_result_with_its_reason(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_LSDYNA_FAIL", "1")
    inputs = solver_inputs(POINT, Rig(), solver="lsdyna", solver_settings=_settings(tmp_path))
    result = solve_inputs(inputs)
    assert result["status"] == "failed"
    assert "Error 20000" in result["reason"]


def test_command_from_the_environment_and_a_missing_program(tmp_path, monkeypatch):
    monkeypatch.setenv("SURROGATE_LSDYNA_COMMAND", "no-such-lsdyna-binary ncpu=2")
    settings = _settings(tmp_path)
    del settings["command"]
    result = solve_inputs(solver_inputs(POINT, Rig(), solver="lsdyna", solver_settings=settings))
    assert result["status"] == "failed"
    assert "no-such-lsdyna-binary: command not found" in result["reason"]


def test_template_content_keys_the_cache_and_an_edit_is_caught(tmp_path):
    template = tmp_path / "deck.k"
    template.write_text(TEMPLATE.read_text())
    settings = _settings(tmp_path, template=str(template))
    # as loading a study does: the settings are checked once, the template hashed
    checked = LsDynaSolver.check_settings(settings)
    first = solver_inputs(POINT, Rig(), solver="lsdyna", solver_settings=checked)
    template.write_text(TEMPLATE.read_text().replace("90.0", "45.0"))
    checked = LsDynaSolver.check_settings(settings)
    second = solver_inputs(POINT, Rig(), solver="lsdyna", solver_settings=checked)
    assert (
        first["solver_settings"]["template_sha256"] != second["solver_settings"]["template_sha256"]
    )
    result = solve_inputs(first)  # inputs hashed before the edit
    assert result["status"] == "failed" and "changed since the study was loaded" in result["reason"]


def test_simulate_api_and_cli_with_an_external_solver(tmp_path, capsys):
    """``surrogate simulate --solver lsdyna`` through the stand-in (not LS-DYNA)."""
    from surrogate._cli import main

    curve = simulate(**POINT, solver="lsdyna", solver_settings=_settings(tmp_path))
    reference = simulate(**POINT)
    assert curve.f60_n == pytest.approx(reference.f60_n, rel=1e-4)
    assert np.isnan(curve.contact_arc_mm).all()  # an external solver does not report it
    command = f"{sys.executable} {FIXTURES / 'fake_lsdyna.py'}"
    args = ["simulate", "--ecoat", "1", "--scoat", "0.2", "--tcoat", "0.012", "--json"]
    args += ["--solver", "lsdyna", "--solver-option", f"template={TEMPLATE}"]
    args += ["--solver-option", f"command={command}"]
    assert main(args) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["f60_n"] == pytest.approx(reference.f60_n, rel=1e-4)


def test_doe_runs_an_external_solver_through_the_pool_and_the_cache(tmp_path):
    """A study with ``kind = "lsdyna"`` (the stand-in, not LS-DYNA): two worker
    processes, every run cached by its input hash, a second batch solves nothing."""
    import surrogate

    command = [sys.executable, str(FIXTURES / "fake_lsdyna.py")]
    (tmp_path / "s.toml").write_text(
        '[study]\nname = "s"\n[targets]\nf60_n = 10.0\n'
        f'[solver]\nkind = "lsdyna"\ntemplate = "{TEMPLATE}"\ncommand = {json.dumps(command)}\n'
    )
    kwargs = {"n": 4, "study": tmp_path / "s.toml", "run": True, "jobs": 2, "progress": False}
    first = surrogate.doe("lhs", out=tmp_path / "a.csv", **kwargs)
    assert (first.n_ok, first.solver_calls, first.cached) == (4, 4, 0)
    again = surrogate.doe(
        "lhs", out=tmp_path / "b.csv", cache_dir=tmp_path / ".solver-cache", **kwargs
    )
    assert (again.n_ok, again.solver_calls, again.cached) == (4, 0, 4)
    samples = surrogate.SampleSet.read(tmp_path / "a.csv")
    assert samples.meta["solver"] == "lsdyna"


def test_the_main_job_takes_the_multi_fidelity_path_with_lsdyna(tmp_path):
    """``kind = "lsdyna"`` through the stand-in (not LS-DYNA: it runs the built-in solver
    and writes rcforc/nodout): the built-in solver is its prior like CalculiX's, every
    expensive run goes through the deck writer and the output parsers, and the correction
    reported is the stand-in's output resolution only."""
    import surrogate

    command = [sys.executable, str(FIXTURES / "fake_lsdyna.py")]
    (tmp_path / "s.toml").write_text(
        '[study]\nname = "s"\n[targets]\nf60_n = 9.958\n'
        f'[solver]\nkind = "lsdyna"\ntemplate = "{TEMPLATE}"\ncommand = {json.dumps(command)}\n'
        "[budget]\nsurrogate_trials = 100\n"
    )
    result = surrogate.run(tmp_path / "s.toml", progress=False)
    assert result.status == "verified", result.message
    assert result.solver_calls == result.calls_to_verify <= 2
    mf = result.multi_fidelity
    assert mf["dropped"] is None and mf["low_fidelity_runs"] > 0
    assert abs(mf["correction"]["f60_percent"]) < 0.1  # the same physics, printed to 7 digits
    assert "lsdyna against the built-in solver" in result.message


def test_an_effect_the_deck_cannot_carry_is_refused_not_dropped(tmp_path):
    """The adapter fills in the coat only: a model with self-weight (or a bare-webbing
    stiffness, or a compliant clamp) is refused before LS-DYNA starts, never run without
    it; a diagnosis skips such a candidate with this reason."""
    from surrogate.solvers import get_solver, model_state_of

    state = model_state_of(1.0, 0.2, 0.012, Rig(), {"gravity": {"areal_mass_g_m2": 1200.0}}, None)
    reason = get_solver("lsdyna").refuses(state)
    assert reason is not None and "not gravity" in reason
    settings = {"template": str(TEMPLATE), "command": "does-not-matter"}
    inputs = solver_inputs(
        POINT,
        Rig(),
        solver="lsdyna",
        effects={"gravity": {"areal_mass_g_m2": 1200.0}},
        solver_settings=get_solver("lsdyna").check_settings(settings),
    )
    result = get_solver("lsdyna").solve(inputs)
    assert result["status"] == "failed" and "not gravity" in result["reason"]
