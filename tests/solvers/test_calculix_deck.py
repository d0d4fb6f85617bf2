"""CalculiX deck writer and .dat parser (no ccx needed)."""

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from surrogate import InputDataError, Rig
from surrogate.effects import ModelState
from surrogate.solvers import CALCULIX_MESHES, _calculix, calculix_deck, parse_calculix_dat
from surrogate.solvers._calculix import (
    MAX_ITERATIONS,
    SLICE_WIDTH_MM,
    _curve,
    _Deck,
    _next_attempt,
    ccx_failure,
    stalled_increment,
)

FIXTURES = Path(__file__).parent / "fixtures"
STATE = ModelState(1000.0, 200.0, 0.012, Rig())


def _blocks(deck: str) -> dict[str, list[str]]:
    """Keyword line → its data lines (first occurrence of each keyword line)."""
    blocks: dict[str, list[str]] = {}
    current = None
    for line in deck.splitlines():
        if line.startswith("**"):
            continue
        if line.startswith("*"):
            current = line
            blocks.setdefault(current, [])
        elif current is not None:
            blocks[current].append(line)
    return blocks


def _coat_tables(deck: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Coat material name → its ``*PLASTIC`` (true stress, true plastic strain) columns."""
    tables: dict[str, list[list[float]]] = {}
    material, rows = None, None
    for line in deck.splitlines():
        if line.startswith("*MATERIAL, NAME="):
            material, rows = line.split("=", 1)[1], None
        elif line.startswith("*"):
            rows = tables.setdefault(material, []) if line == "*PLASTIC" else None
        elif rows is not None:
            rows.append([float(v) for v in line.split(",")])
    return {name: tuple(np.array(rows).T) for name, rows in tables.items()}


def _signed_volume(corners: np.ndarray) -> float:
    """Triple product of the edges 1-2, 1-4, 1-5 of a brick (positive: valid ordering)."""
    return float(np.dot(np.cross(corners[1] - corners[0], corners[3] - corners[0]),
                        corners[4] - corners[0]))  # fmt: skip


@pytest.mark.parametrize("mesh", sorted(CALCULIX_MESHES))
def test_every_element_has_a_positive_jacobian(mesh):
    deck = _Deck(STATE, CALCULIX_MESHES[mesh])
    xyz = {node: np.array(c) for node, *c in deck.strip_nodes()}
    probe_nodes, probe_elements = deck.probe()
    xyz.update({node: np.array(c) for node, *c in probe_nodes})
    bricks = [e for layer in deck.strip_elements().values() for e in layer] + probe_elements
    volumes = [_signed_volume(np.array([xyz[n] for n in e[1:9]])) for e in bricks]
    assert min(volumes) > 0.0
    for element in (e for layer in deck.strip_elements().values() for e in layer):
        assert len(set(element[1:])) == 20 and all(n in xyz for n in element[1:])


def test_layers_follow_the_coat_core_coat_section():
    deck = _Deck(STATE, CALCULIX_MESHES["coarse"])
    xyz = {node: np.array(c) for node, *c in deck.strip_nodes()}
    for layer, (low, high) in {
        "BOTCOAT": (-0.6, -0.588),
        "CORE": (-0.588, 0.588),
        "TOPCOAT": (0.588, 0.6),
    }.items():
        z = np.array([[xyz[n][2] for n in e[1:]] for e in deck.strip_elements()[layer]])
        assert z.min() == pytest.approx(low) and z.max() == pytest.approx(high)
    y = np.array([c[1] for c in xyz.values()])
    assert y.min() == 0.0 and y.max() == pytest.approx(SLICE_WIDTH_MM)


def test_materials_contact_and_step_carry_the_inputs():
    deck = calculix_deck(STATE, mesh="coarse")
    blocks = _blocks(deck)
    assert blocks["*ELASTIC"][0] == "1000, 0."  # Ecoat [MPa], ν = 0
    # Scoat a nominal yield stress: true stress Scoat·exp(εp), so a stretched coat's
    # shrinking section carries Scoat per undeformed area and does not neck; each coat
    # has its material (TABLE_GROWTH), the same table in the deck
    for coat, (stress, strain) in _coat_tables(deck).items():
        assert f"*SOLID SECTION, ELSET={coat}, MATERIAL={coat}" in blocks
        assert strain[0] == 0.0 and strain[-1] >= 2.0 and np.all(np.diff(strain) > 0.0)
        assert stress * np.exp(-strain) == pytest.approx(200.0, rel=1e-8)
    assert blocks["*FRICTION"] == ["0.1, 100"]  # μ, stick slope K/10
    assert blocks["*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR"] == ["1000"]
    rotation = [line for line in blocks["*BOUNDARY"] if line.endswith(f"{-math.pi / 2:.12g}")]
    assert len(rotation) == 1  # the clamp's rotation node turns −90° about y
    # coarse: fixed increments of 1.125° (automatic ones moved the curve by more than a
    # coat 0.1 % thicker does)
    assert "*STATIC" not in blocks
    assert [float(v) for v in blocks["*STATIC, DIRECT"][0].split(",")] == pytest.approx(
        [1.125 / 90.0, 1.0]
    )
    fine = _blocks(calculix_deck(STATE, mesh="fine"))
    assert [float(v) for v in fine["*STATIC"][0].split(",")][3] == pytest.approx(1.0 / 90.0)
    assert "*STEP, NLGEOM, INC=5000" in blocks
    # ccx's contact defaults but alea (its random part) 0: the same deck, the same curve
    assert blocks["*CONTROLS, PARAMETERS=CONTACT"] == ["0.001, 0., 100, 60"]


def test_hardening_friction_and_end_load_options():
    state = ModelState(1000.0, 200.0, 0.012, Rig(friction=0.0, tension_n=19.0), 0.05)
    deck = calculix_deck(state, mesh="coarse")
    blocks = _blocks(deck)
    # linear hardening: nominal stress Scoat + H·εp, H = E·r/(1 − r)
    tables = _coat_tables(deck)
    assert sorted(tables) == ["BOTCOAT", "TOPCOAT"]
    for stress, strain in tables.values():
        hardened = 200 + 1000 * 0.05 / 0.95 * strain
        assert stress * np.exp(-strain) == pytest.approx(hardened, rel=1e-8)
    assert "*FRICTION" not in blocks
    loads = [float(line.split(",")[2]) for line in blocks["*CLOAD"]]
    assert sum(loads) == pytest.approx(19.0 * SLICE_WIDTH_MM / 38.0)  # the slice's share


def test_each_coat_takes_its_own_table_growth(monkeypatch):
    """``TABLE_GROWTH`` (what ``benchmarks/calculix_gap.py`` varies): growth 0 is a flat
    true stress, 1 a nominal Scoat in tension, per coat."""
    monkeypatch.setattr(_calculix, "TABLE_GROWTH", {"BOTCOAT": 0.0, "TOPCOAT": 1.0})
    tables = _coat_tables(calculix_deck(STATE, mesh="coarse"))
    bottom, top = tables["BOTCOAT"], tables["TOPCOAT"]
    assert bottom[0] == pytest.approx(200.0, rel=1e-8)
    assert top[0] * np.exp(-top[1]) == pytest.approx(200.0, rel=1e-8)
    assert top[0][-1] > 7 * bottom[0][-1]  # exp(2) at εp = 2


def test_a_retry_keeps_the_first_attempts_increments_up_to_where_it_stopped():
    """After the mesh's fixed increments stopped at 88.87° (ccx's rotation of the 79th
    increment, a hair under 79 × 1.125°): one step, 79 increments of 1.125° and 2 of
    0.5625°, each one step-time unit of ``DIRECT``; rotation and end load on one
    amplitude, so each reaches at every increment what it reached in the first attempt."""
    coarse = CALCULIX_MESHES["coarse"]
    retry = _next_attempt(coarse, coarse, 88.87497865, 90.0)
    assert retry == replace(coarse, finer_from_deg=88.875)
    state = ModelState(1000.0, 200.0, 0.012, Rig(tension_n=19.0))
    blocks = _blocks(calculix_deck(state, mesh=retry))
    steps = 79 + 2
    assert float(blocks["*STATIC, DIRECT"][0].split(",")[0]) == pytest.approx(1 / steps)
    times, values = (
        np.array([float(v) for v in blocks["*AMPLITUDE, NAME=ROTATION"][0].split(",")])
        .reshape(3, 2)
        .T
    )
    assert times == pytest.approx([0.0, 79 / steps, 1.0])
    assert values == pytest.approx([0.0, 88.875 / 90.0, 1.0])
    assert "*BOUNDARY, AMPLITUDE=ROTATION" in blocks and "*CLOAD, AMPLITUDE=ROTATION" in blocks
    assert "*AMPLITUDE" not in calculix_deck(state, mesh=coarse)  # the deck's own: none
    # where not one increment was reached, the retry is half the size from the start
    assert _next_attempt(coarse, coarse, 0.5, 90.0) == replace(coarse, fixed_increment_deg=0.5625)
    # where it reached the end and its last increment still failed, the same increments
    # would fail again: automatic ones next
    ended = _next_attempt(coarse, coarse, 89.99999, 90.0)
    assert ended.fixed_increment_deg is None
    assert ended == _next_attempt(coarse, retry, 1, 90)
    # then automatic increments of at most the fixed size, starting with it (the fixed
    # path up to a cutback), then the mesh's own automatic ones
    after = [_next_attempt(coarse, retry, 50.0, 90.0)]
    after.append(_next_attempt(coarse, after[0], 50.0, 90.0))
    assert [m.fixed_increment_deg for m in after] == [None, None]
    assert [m.max_increment_deg for m in after] == [1.125, 3.0]
    assert [m.initial_increment_deg for m in after] == [1.125, 1.5]
    assert _next_attempt(coarse, after[1], 50.0, 90.0) is None
    half = _next_attempt(coarse, coarse, 0.5, 90.0)
    assert _next_attempt(coarse, half, 0.5, 90.0) == after[0]
    # the fine mesh's automatic increments: at most half its largest, then none
    fine = CALCULIX_MESHES["fine"]
    smaller = _next_attempt(fine, fine, 50.0, 90.0)
    assert (smaller.fixed_increment_deg, smaller.max_increment_deg) == (None, 0.5)
    assert _next_attempt(fine, smaller, 50.0, 90.0) is None


def test_bad_mesh_and_unsupported_effect_are_input_errors():
    with pytest.raises(InputDataError, match="mesh must be one of"):
        calculix_deck(STATE, mesh="medium")
    with pytest.raises(InputDataError, match="membrane_bending"):
        calculix_deck(STATE.replace(extra_stiffness_nmm=1.0), mesh="coarse")
    with pytest.raises(InputDataError, match="gravity"):
        calculix_deck(STATE.replace(line_load_n_mm=1e-3), mesh="coarse")
    with pytest.raises(InputDataError, match="clamp_slip"):
        calculix_deck(STATE.replace(clamp_stiffness_nmm=100.0), mesh="coarse")


def test_dat_parser_on_real_ccx_output():
    """ccx 2.20 output of the coarse deck (fixtures/README.md)."""
    text = (FIXTURES / "ccx220_coarse_paper_optimum.dat").read_text()
    history = parse_calculix_dat(text)
    assert history.time.size == text.count("total force (fx,fy,fz)") == 32
    np.testing.assert_allclose(
        history.probe_force_n[0], [-2.466778e-04, -3.148741e-09, -1.369525e-03]
    )
    assert history.rotation_rad[0] == pytest.approx(-2.617994e-02)
    assert history.time[-1] == 1.0 and history.rotation_rad[-1] == pytest.approx(-math.pi / 2)
    result = _curve(history, STATE)
    assert result["status"] == "ok"
    assert result["angle_deg"] == list(np.arange(91.0))
    # the magnitude over the full width at 90°: the fixture's last block × b/slice
    assert result["force_n"][90] == pytest.approx(
        math.hypot(2.822191e-02, 5.755216e-02) * 38.0 / SLICE_WIDTH_MM
    )
    # the coat never yields: the curve does not saturate (the coarse contact facets
    # leave a ripple of a few 0.01 N near 90°, far below the 10 % secant criterion)
    assert result["saturated"] is False and result["theta_sat_deg"] == 90.0
    assert np.all(np.diff(result["force_n"][:80]) > 0)


def test_a_history_that_stops_short_is_a_failed_run():
    text = (FIXTURES / "ccx220_coarse_paper_optimum.dat").read_text()
    cut = text[: [m.start() for m in re.finditer(" total force", text)][20]]
    result = _curve(parse_calculix_dat(cut), STATE)
    assert result["status"] == "failed" and "stopped at" in result["reason"]


def test_ccx_reason_is_its_first_error_line():
    stdout = "increment 12 attempt 5\n *ERROR: too many cutbacks\n best solution and residuals\n"
    assert ccx_failure(stdout, 201) == "*ERROR: too many cutbacks"
    assert ccx_failure("Job finished\n", 1) == "ccx exited with code 1 (Job finished)"


@pytest.mark.parametrize("exit_code", ["201", "0"])
def test_ccx_stopping_is_a_failed_run_with_its_reason(tmp_path, monkeypatch, exit_code):
    """The run path with a stand-in for ccx (fixtures/fake_ccx.py, NOT CalculiX) that
    stops after 10 increments with ccx's own message, on the first try and on the retries."""
    import sys

    monkeypatch.setenv("FAKE_CCX_EXIT", exit_code)
    from surrogate.solvers._batch import solve_inputs, solver_inputs

    settings = {
        "command": [sys.executable, str(FIXTURES / "fake_ccx.py")],
        "workdir_root": str(tmp_path / "work"),
    }
    point = {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012}
    result = solve_inputs(solver_inputs(point, Rig(), solver="calculix", solver_settings=settings))
    assert result["status"] == "failed"
    # the 10th block
    stopped = "ccx did not reach 90°: *ERROR: too many cutbacks (last converged 26.25°)"
    # The stand-in stops the same way when retried: every attempt's reason named. The
    # first retry keeps 1.125° up to the last whole increment reached (23 × 1.125°).
    assert result["reason"] == (
        f"with fixed increments of 1.125°: {stopped}; "
        f"again with fixed increments of 1.125° to 25.875°, then 0.5625°: {stopped}; "
        f"again with automatic increments of at most 1.125°: {stopped}; "
        f"again with automatic increments of at most 3°: {stopped}"
    )
    assert list((tmp_path / "work").iterdir()) == []


CVG_HEAD = """ SUMMARY OF C0NVERGENCE INFORMATION
  STEP   INC  ATT   ITER     CONT.   RESID.        CORR.      RESID.      CORR.
                              EL.    FORCE         DISP       FLUX        TEMP.
                              (#)     (%)           (%)        (%)         (%)
"""


def _cvg(tmp_path, rows):
    path = tmp_path / "bending.cvg"
    body = "".join(
        f"{1:6d}{inc:6d}{att:6d}{it:7d}{144:9d}  0.3631E+02  0.3759E+02  0.0000E+00  0.0000E+00\n"
        for it, (inc, att) in enumerate(rows, start=1)
    )
    path.write_text(CVG_HEAD + body)
    return path


def test_a_ccx_whose_contact_flips_is_stalled(tmp_path):
    """ccx's convergence file (its columns as ccx 2.20 writes them): more than
    MAX_ITERATIONS in one attempt of one increment anywhere in it is a stall."""
    assert stalled_increment(tmp_path / "missing.cvg") is None  # not written yet
    settled = [(1, 1)] * 8 + [(2, 1)] * 30 + [(2, 2)] * MAX_ITERATIONS
    assert stalled_increment(_cvg(tmp_path, settled)) is None
    stalled = f"ccx's contact did not settle: more than {MAX_ITERATIONS} iterations in "
    flipping = [(61, 1)] * 5 + [(62, 1)] * (MAX_ITERATIONS + 1)
    assert stalled_increment(_cvg(tmp_path, flipping)) == stalled + "increment 62 (attempt 1)"
    # the same verdict after ccx settled and went on: a rule of the file, not of the moment
    settled_late = flipping + [(63, 1)] * 4
    assert stalled_increment(_cvg(tmp_path, settled_late)) == stalled + "increment 62 (attempt 1)"
    (tmp_path / "half.cvg").write_text(CVG_HEAD + "     1     2     1\n")  # half-written
    assert stalled_increment(tmp_path / "half.cvg") is None


FLIPPING_CCX = """import shutil, sys, time
shutil.copy(sys.argv[1], "bending.cvg")
time.sleep({sleep})
"""


@pytest.mark.parametrize("sleep", [60, 0])
def test_a_stalled_ccx_is_retried_and_named(tmp_path, sleep):
    """A stand-in for ccx (NOT CalculiX) that writes a .cvg with an increment that does
    not settle: stopped while it runs (sleep 60) or judged at its end (sleep 0) — the
    same verdict — and retried with each deck in turn, every reason named."""
    import sys

    from surrogate.solvers._batch import solve_inputs, solver_inputs

    script = tmp_path / "flipping_ccx.py"
    script.write_text(FLIPPING_CCX.format(sleep=sleep))
    cvg = _cvg(tmp_path, [(7, 1)] * (MAX_ITERATIONS + 1))
    settings = {
        "command": [sys.executable, str(script), str(cvg)],
        "workdir_root": str(tmp_path / "work"),
        "timeout_s": 120,
    }
    point = {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012}
    result = solve_inputs(solver_inputs(point, Rig(), solver="calculix", solver_settings=settings))
    assert result["status"] == "failed"
    stalled = (
        f"ccx's contact did not settle: more than {MAX_ITERATIONS} iterations in increment 7 "
        "(attempt 1) (last converged 0.00°)"
    )
    assert result["reason"] == (
        f"with fixed increments of 1.125°: {stalled}; "
        f"again with fixed increments of 0.5625°: {stalled}; "
        f"again with automatic increments of at most 1.125°: {stalled}; "
        f"again with automatic increments of at most 3°: {stalled}"
    )
