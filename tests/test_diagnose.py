"""The diagnosis on data with a hidden effect and decoy covariates, and without one.

Seeded synthetic data (surrogate.calibration._synthetic); the truth is known to the test only.
The per-effect sweep over every built-in effect is benchmarks/diagnosis.py's job.
"""

import json

import pytest

import surrogate
from surrogate._cli import main
from surrogate.calibration._synthetic import synthetic_measurements
from tests.studies import write_study

pytestmark = pytest.mark.slow  # calibrations and diagnoses: CI runs them, the dev loop not

TRUTH = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
NOISE = 0.05
# tension and direction vary; temperature is a decoy column that does not matter
TESTS = [
    {"test_id": "a1", "tension_n": 0.0, "direction": "warp", "temperature_c": 21.0},
    {"test_id": "a2", "tension_n": 0.0, "direction": "warp", "temperature_c": 24.5},
    {"test_id": "b", "tension_n": 20.0, "direction": "weft", "temperature_c": 22.0},
    {"test_id": "c", "tension_n": 40.0, "direction": "warp", "temperature_c": 23.0},
]
CANDIDATES = ["tension", "anisotropy", "hardening", "membrane_bending"]


def _study(tmp_path, hidden):
    table = synthetic_measurements(TESTS, coating=TRUTH, effects=hidden, noise_n=NOISE, seed=3)
    return write_study(
        tmp_path,
        table,
        """
        [study]
        name = "diag"
        [measurements]
        file = "tests.csv"
        [budget]
        surrogate_trials = 100
        """,
        ranges=True,
    )


def test_hidden_tension_is_named_and_adding_it_brings_the_error_to_the_noise(tmp_path):
    path = _study(tmp_path, {"tension": {"k_e": 0.006, "k_s": 0.006}})
    result = surrogate.diagnose(path, candidates=CANDIDATES, progress=False)
    assert result.systematic and result.p_value < 1e-6
    assert result.ranking[0]["effect"] == "tension"
    assert result.ranking[0]["delta_bic"] < -10
    assert result.unexplained is None
    assert result.verdict.startswith("missing effect: tension")
    follows = [f["covariate"] for f in result.follows if f["significant"]]
    assert follows[0] == "tension_n" and "temperature_c" not in follows[:1]
    # add it, watch the error fall: the diagnosis of the model with it calibrates it (as
    # `surrogate calibrate` would, the same run) and the ladder keeps both calibrations
    again = surrogate.diagnose(path, effects=["tension"], candidates=CANDIDATES, progress=False)
    assert again.rmse_n <= 1.3 * NOISE
    assert not again.systematic
    models = {step["model"]: step for step in again.ladder}
    assert models["tension"]["rmse_n"] < 0.2 * models["base"]["rmse_n"]


def test_no_false_alarm_on_data_without_a_hidden_effect(tmp_path, capsys):
    path = _study(tmp_path, None)
    assert main(["diagnose", str(path), "--json", "--effect", "tension"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) >= {
        "rmse_n",
        "noise_n",
        "systematic",
        "where",
        "ranking",
        "unexplained",
        "verdict",
    }
    assert out["systematic"] is False
    assert out["unexplained"] is None
    assert out["verdict"].startswith("no systematic misfit")
    deltas = [e["delta_bic"] for e in out["ranking"]]
    assert deltas == sorted(deltas)


@pytest.mark.parametrize(
    "option", [["--effect", "nonsense"], ["--plugin", "no_module_q"], ["--jobs", "0"]]
)
def test_bad_diagnose_options_are_one_line_errors(tmp_path, capsys, option):
    path = _study(tmp_path, None)
    with pytest.raises(SystemExit) as exit_info:
        main(["diagnose", str(path), *option])
    assert exit_info.value.code == 2
    assert "\n" not in capsys.readouterr().err.strip()


def test_a_diagnosis_after_the_same_calibration_takes_it_and_says_the_same(tmp_path):
    """`surrogate calibrate`, then `surrogate diagnose` on the same study, data and code:
    the diagnosis takes the recorded calibration instead of running it again, and says
    what a diagnosis that ran it says (the same verdict, figures and run counts)."""
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    candidates = ["tension", "anisotropy"]
    ran = surrogate.diagnose(
        _study(tmp_path / "ran", hidden), candidates=candidates, progress=False
    )
    path = _study(tmp_path / "taken", hidden)
    calibration = surrogate.calibrate(path, progress=False)
    taken = surrogate.diagnose(path, candidates=candidates, progress=False)
    assert ran.reused_calibration is None
    assert taken.reused_calibration == calibration.study
    assert taken.rmse_n == ran.rmse_n
    assert taken.verdict == ran.verdict and taken.solver_calls == ran.solver_calls
    figures = [(c["effect"], c["rmse_n"], c["delta_bic"]) for c in ran.ranking]
    assert [(c["effect"], c["rmse_n"], c["delta_bic"]) for c in taken.ranking] == figures


def test_a_recorded_calibration_is_taken_only_for_the_same_inputs(tmp_path, monkeypatch):
    """The key of a calibration's inputs changes with the model, the budget, the tests and
    the measurements' bytes; there is none for an effect not the package's own (a plug-in,
    or a built-in name a plug-in replaced) or an external solver, with or without the
    built-in prior."""
    from dataclasses import replace

    from surrogate.calibration._calibrate import calibration_key
    from surrogate.calibration._problem import load_calibration
    from surrogate.effects import _base, get_effect

    path = _study(tmp_path, None)

    def key(effects=(), budget=200, tests=None, **solver):
        spec = replace(load_calibration(path, effects, ())[0], **solver)
        return calibration_key(spec, effects, budget, tests)

    first = key()
    assert first is not None and key() == first  # loaded again: the same
    changed = [key(("tension",)), key(budget=100), key(tests=["a1", "b", "c"])]
    assert first not in changed and len(set(changed)) == 3
    assert key(solver="calculix") is None
    assert key(solver="calculix", multi_fidelity=False) is None

    class Tension(type(get_effect("tension"))):  # a plug-in's, under the built-in name
        pass

    monkeypatch.setitem(_base._REGISTRY, "tension", Tension())
    assert key(("tension",)) is None
    monkeypatch.undo()
    data = tmp_path / "tests.csv"
    data.write_text(data.read_text(encoding="utf-8") + "\n", encoding="utf-8")
    assert key() != first
