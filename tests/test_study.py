"""Study files: validated on load; a bad file is one line, exit 2, nothing written."""

import subprocess
import sys
from pathlib import Path

import pytest

from surrogate import InputDataError, load_study

STUDIES = Path(__file__).resolve().parents[1] / "studies"
GOOD = (STUDIES / "paper_coating.toml").read_text()


def test_shipped_study_loads():
    spec = load_study(STUDIES / "paper_coating.toml")
    assert spec.name == "paper-coating" and spec.targets.f60_n == pytest.approx(9.958)
    assert spec.space.names == ("ecoat_gpa", "scoat_gpa", "tcoat_mm")
    assert spec.constraints.theta_sat_deg_min == 80.0
    assert spec.preference_order == ("tcoat_mm", "scoat_gpa")
    assert spec.default_storage().startswith("sqlite:///")
    assert spec.default_storage().endswith("studies/paper-coating.db")


def test_shipped_target_is_the_solver_at_the_paper_optimum():
    import surrogate

    assert surrogate.simulate(1.0, 0.2, 0.012).f60_n == pytest.approx(
        load_study(STUDIES / "paper_coating.toml").targets.f60_n, abs=5e-4
    )


BAD = {
    "toml-syntax": ("[study\nname = 'x'", "not valid TOML"),
    "unknown-section": (GOOD + "\n[extras]\na = 1\n", "unknown section 'extras'"),
    "unknown-key": (GOOD.replace("seed = 0", "seed = 0\nsead = 1"), "unknown in [study] 'sead'"),
    "bad-name": (GOOD.replace('name = "paper-coating"', 'name = "a b/c"'), "[study] name"),
    "negative-seed": (GOOD.replace("seed = 0", "seed = -1"), "study.seed"),
    "solver-kind": (GOOD.replace('kind = "builtin"', 'kind = "abaqus"'), "[solver] kind"),
    "rig-negative": (GOOD.replace("width_mm = 38.0", "width_mm = -38.0"), "width_mm must be > 0"),
    "rig-unknown": (
        GOOD.replace("friction = 0.1", "friction = 0.1\nfrixion = 0.2"),
        "unknown in [rig] 'frixion'",
    ),
    "low-above-high": (
        GOOD.replace("low = 0.5,  high = 4.0", "low = 5.0,  high = 4.0"),
        "`low < high` must hold",
    ),
    "unknown-parameter": (
        GOOD.replace("tcoat_mm  = {", "density = { low = 1, high = 2 }\ntcoat_mm  = {"),
        "'density' is not a coating parameter",
    ),
    "wrong-unit": (
        GOOD.replace(
            "low = 0.5,  high = 4.0, log = true",
            'low = 500,  high = 4000, log = true, unit = "MPa"',
        ),
        "ecoat_gpa is in GPa",
    ),
    "target-zero": (GOOD.replace("f60_n = 9.958", "f60_n = 0"), "targets.f60_n must be"),
    "target-text": (GOOD.replace("f60_n = 9.958", 'f60_n = "ten"'), "targets.f60_n must be"),
    "tolerance": (GOOD.replace("tolerance = 0.01", "tolerance = 2"), "targets.tolerance"),
    "theta-min": (
        GOOD.replace("theta_sat_deg_min = 80.0", "theta_sat_deg_min = 120.0"),
        "theta_sat_deg_min must be ≤ 90",
    ),
    "preference": (
        GOOD.replace('order = ["tcoat_mm", "scoat_gpa"]', 'order = ["cost"]'),
        "[preferences] order names 'cost'",
    ),
    "budget": (
        GOOD.replace("max_solver_calls = 30", "max_solver_calls = 2"),
        "budget.max_solver_calls (2) must be ≥",
    ),
    "budget-float": (
        GOOD.replace("initial_samples = 5", "initial_samples = 5.5"),
        "budget.initial_samples must be a whole number",
    ),
    "no-target": (
        GOOD.replace("f60_n = 9.958 ", "").replace("f60_n = 9.958", ""),
        "needs [targets] f60_n or [measurements] file",
    ),
    "escaping-path": (
        GOOD + '\n[measurements]\nfile = "../../../../etc/passwd"\n',
        "leaves the project folder",
    ),
    "effects-not-a-list": (GOOD + '\n[model]\neffects = "tension"\n', "[model] effects must"),
    "effects-twice": (
        GOOD + '\n[model]\neffects = ["tension", "tension"]\n',
        "names an effect twice",
    ),
    "calibration-budget": (
        GOOD.replace("[budget]", "[budget]\ncalibration_solver_calls = 0"),
        "budget.calibration_solver_calls",
    ),
    "noise-negative": (
        GOOD + '\n[measurements]\nfile = "m.csv"\nnoise_n = -1\n',
        "measurements.noise_n",
    ),
    "multi-fidelity": (
        GOOD.replace('kind = "builtin"', 'kind = "builtin"\nmulti_fidelity = "yes"'),
        "[solver] multi_fidelity must be true or false, got 'yes'",
    ),
}


def test_a_calibration_budget_below_a_design_loads(tmp_path):
    """What a calibration needs is its loop's (one verification with a built-in prior):
    the study file takes any whole number of runs ≥ 1 (a floor of 10 refused 2)."""
    path = tmp_path / "s.toml"
    path.write_text(GOOD.replace("[budget]", "[budget]\ncalibration_solver_calls = 2"))
    assert load_study(path).budget.calibration_solver_calls == 2


def test_a_main_job_budget_below_the_design_loads_where_the_built_in_solver_is_the_prior(
    tmp_path,
):
    """With CalculiX and its built-in prior the main job starts from the corrected
    model's answer (one run), not from ``initial_samples`` runs on CalculiX: a budget of 2
    loads there, and is refused where the design runs on the full solver."""
    path = tmp_path / "s.toml"
    small = GOOD.replace("max_solver_calls = 30", "max_solver_calls = 2")
    path.write_text(small.replace('kind = "builtin"', 'kind = "calculix"'))
    assert load_study(path).budget.max_solver_calls == 2
    single = 'kind = "calculix"\nmulti_fidelity = false'
    path.write_text(small.replace('kind = "builtin"', single))
    with pytest.raises(InputDataError, match=r"budget.max_solver_calls \(2\) must be ≥"):
        load_study(path)


def test_multi_fidelity_is_on_for_an_external_solver_unless_switched_off(tmp_path):
    path = tmp_path / "s.toml"
    calculix = GOOD.replace('kind = "builtin"', 'kind = "calculix"')
    path.write_text(calculix)
    assert load_study(path).low_fidelity
    path.write_text(
        calculix.replace('kind = "calculix"', 'kind = "calculix"\nmulti_fidelity = false')
    )
    assert not load_study(path).low_fidelity
    path.write_text(GOOD)  # the built-in solver is its own low fidelity
    assert not load_study(path).low_fidelity
    shipped = load_study(STUDIES / "paper_coating_calculix.toml")
    assert shipped.solver == "calculix" and shipped.low_fidelity


@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_study_file_one_line_exit_2_nothing_written(tmp_path, kind):
    text, fragment = BAD[kind]
    folder = tmp_path / "studies"
    folder.mkdir()
    path = folder / "s.toml"
    path.write_text(text)
    with pytest.raises(InputDataError) as caught:
        load_study(path)
    assert fragment in str(caught.value)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    completed = subprocess.run(
        [sys.executable, "-m", "surrogate", "run", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert completed.returncode == 2
    lines = completed.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], completed.stderr
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # no storage, no cache
