"""Each built-in effect shows its signature, and nothing else."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

import surrogate
from surrogate.physics import bending_stiffness

PAPER = dict(ecoat_gpa=1.0, scoat_gpa=0.2, tcoat_mm=0.012)
YIELDING = dict(ecoat_gpa=2.0, scoat_gpa=0.1, tcoat_mm=0.05)  # yields at ~17°


def _force(effects=None, conditions=None, coating=PAPER):
    return surrogate.simulate(**coating, effects=effects, conditions=conditions).force_n


def test_anisotropy_changes_only_weft_tests():
    on = {"anisotropy": {"a_e": 0.5, "a_s": 0.5}}
    np.testing.assert_array_equal(_force(on, {"direction": "warp"}), _force())
    weft = _force(on, {"direction": "weft"})
    np.testing.assert_allclose(weft[1:30], 0.5 * _force()[1:30], rtol=1e-6)  # elastic: ∝ E


def test_hardening_changes_nothing_before_first_yield():
    base = surrogate.simulate(**YIELDING)
    hard = surrogate.simulate(**YIELDING, effects={"hardening": {"ratio": 0.05}})
    first_yield = int(base.theta_sat_deg) - 8  # well inside the elastic rise
    # identical up to round-off (the two runs take different Newton paths later on)
    np.testing.assert_allclose(
        hard.force_n[:first_yield], base.force_n[:first_yield], rtol=1e-12, atol=1e-12
    )
    assert hard.force_n[-1] > 1.02 * base.force_n[-1]  # the plateau rises


def test_tension_effect_changes_nothing_at_zero_tension():
    on = {"tension": {"k_e": 0.02, "k_s": 0.02}}
    np.testing.assert_array_equal(_force(on, {"tension_n": 0.0}), _force())
    loaded = _force(None, {"tension_n": 10.0})
    stiffer = _force(on, {"tension_n": 10.0})
    assert stiffer[30] > loaded[30] * 1.1  # Ecoat·(1 + 0.02·10) in the elastic rise


def test_rate_effect_changes_nothing_at_the_reference_rate():
    on = {"rate": {"c_e": 0.1, "c_s": 0.1}}
    np.testing.assert_array_equal(_force(on, {"rate_deg_s": 90.0}), _force())
    assert _force(on, {"rate_deg_s": 900.0})[30] > _force()[30]
    assert _force(on, {"rate_deg_s": 9.0})[30] < _force()[30]


def test_membrane_bending_adds_its_stiffness():
    d = bending_stiffness(1000.0, 0.012, 1.2)
    on = _force({"membrane_bending": {"d0_nmm": 0.5 * d}})
    np.testing.assert_allclose(on[1:], 1.5 * _force()[1:], rtol=1e-6)  # elastic: ∝ D


def test_friction_effect_replaces_the_rigs_friction_and_is_off_by_default():
    np.testing.assert_array_equal(_force({"friction": {}}), _force())
    high = surrogate.simulate(**PAPER, effects={"friction": {"mu": 0.3}})
    rig = surrogate.simulate(**PAPER, rig=surrogate.Rig(friction=0.3))
    np.testing.assert_array_equal(high.force_n, rig.force_n)


@pytest.mark.parametrize(
    ("effects", "conditions", "fragment"),
    [
        ({"gravitas": {}}, None, "unknown effect 'gravitas'"),
        ({"hardening": {"ratio": 0.9}}, None, "hardening.ratio must be in"),
        ({"hardening": {"slope": 0.1}}, None, "has no parameter 'slope'"),
        (None, {"direction": "diagonal"}, "direction must be warp or weft"),
        (None, {"temperature_c": 20}, "unknown test condition"),
        (None, {"rate_deg_s": -1}, "rate_deg_s must be > 0"),
    ],
)
def test_bad_effects_and_conditions_are_refused(effects, conditions, fragment):
    with pytest.raises(surrogate.InputDataError, match=fragment):
        surrogate.simulate(**PAPER, effects=effects, conditions=conditions)


PLUGIN = textwrap.dedent('''
    import surrogate


    class Softening(surrogate.Effect):
        """Coat modulus falls with temperature: Ecoat·(1 − k·(T − 23 °C))."""

        name = "softening"
        parameters = (surrogate.EffectParameter("k", 0.0, 0.02, 0.0, "1/K"),)
        reads = ("tension_n",)

        def apply(self, state, values, conditions):
            return state.replace(ecoat_mpa=state.ecoat_mpa * (1 - values["k"] * 10))


    surrogate.register_effect(Softening)
''')


def test_plugin_effect_from_a_module_named_on_the_command_line(tmp_path):
    (tmp_path / "my_effects.py").write_text(PLUGIN)
    base = subprocess.run(
        [
            sys.executable,
            "-m",
            "surrogate",
            "simulate",
            "--ecoat",
            "1",
            "--scoat",
            "0.2",
            "--tcoat",
            "0.012",
            "--json",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    soft = subprocess.run(
        [
            sys.executable,
            "-m",
            "surrogate",
            "simulate",
            "--ecoat",
            "1",
            "--scoat",
            "0.2",
            "--tcoat",
            "0.012",
            "--plugin",
            "my_effects",
            "--effect",
            "softening:k=0.01",
            "--json",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"},
        timeout=120,
    )
    assert soft.returncode == 0, soft.stderr
    import json

    ratio = json.loads(soft.stdout)["f60_n"] / json.loads(base.stdout)["f60_n"]
    assert ratio == pytest.approx(0.9, rel=1e-6)  # elastic: F ∝ Ecoat
    missing = subprocess.run(
        [
            sys.executable,
            "-m",
            "surrogate",
            "simulate",
            "--ecoat",
            "1",
            "--scoat",
            "0.2",
            "--tcoat",
            "0.012",
            "--plugin",
            "no_such_module",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert missing.returncode == 2 and "cannot import plug-in module" in missing.stderr


def test_gravity_lets_the_strip_sag_off_the_probe_and_costs_its_weight_share():
    soft = dict(ecoat_gpa=0.05, scoat_gpa=0.01, tcoat_mm=0.012)
    base = surrogate.simulate(**soft)
    heavy = surrogate.simulate(**soft, effects={"gravity": {"areal_mass_g_m2": 1200}})
    assert base.force_n[1] > 0  # without weight the probe is touched from the start
    assert heavy.force_n[1] == 0.0 and heavy.force_n[3] == 0.0  # sagged off the probe
    # once in contact, the probe carries less: the weight's moment about the clamp
    # (weight W at mid-length 17.5 mm, lever shortened by the rotation) over l = 10 mm
    weight = 1200e-9 * 9.80665 * 38.0 * 35.0
    drop = base.force_n[40:] - heavy.force_n[40:]
    assert np.all(drop > 0.3 * weight * 17.5 / 10) and np.all(drop < 1.2 * weight * 17.5 / 10)
    zero = _force({"gravity": {"areal_mass_g_m2": 0.0}})
    np.testing.assert_array_equal(zero, _force())


def test_clamp_slip_softens_the_rise_and_vanishes_for_a_stiff_clamp():
    slip = _force({"clamp_slip": {"k_nmm_rad": 10.0}})
    rigid = _force()
    # small angles: a spring in series with the strip, F ∝ 1/(1/k_strip + 1/k_clamp)
    k_strip = 3 * bending_stiffness(1000.0, 0.012, 1.2) * 38.0 / 10.0**2 * 10.0  # F·l/θ
    k_clamp = 10.0 * 38.0
    expected = 1.0 / (1.0 + k_strip / k_clamp)
    np.testing.assert_allclose(slip[1] / rigid[1], expected, rtol=0.03)
    stiff = _force({"clamp_slip": {"k_nmm_rad": 2000.0}})
    np.testing.assert_allclose(stiff[1:], rigid[1:], rtol=0.02)
    np.testing.assert_array_equal(_force({"clamp_slip": {}}), rigid)  # off: a rigid clamp


def test_a_model_state_replaced_is_dataclasses_replace():
    """``ModelState.replace`` skips ``__init__`` (the search replaces ~10⁶ states): the same
    state as ``dataclasses.replace`` for each field, its error for an unknown one, and a
    subclass's ``__post_init__`` still runs."""
    import dataclasses

    from surrogate import Rig
    from surrogate.effects import ModelState

    state = ModelState(1000.0, 200.0, 0.012, Rig(), hardening_ratio=0.1)
    changes = {
        "ecoat_mpa": 900.0,
        "scoat_mpa": 150.0,
        "tcoat_mm": 0.02,
        "rig": Rig(friction=0.3),
        "hardening_ratio": 0.2,
        "extra_stiffness_nmm": 1.5,
        "line_load_n_mm": 1e-4,
        "clamp_stiffness_nmm": 200.0,
    }
    for name, value in changes.items():
        ours = state.replace(**{name: value})
        assert type(ours) is ModelState
        assert ours == dataclasses.replace(state, **{name: value}) != state
        assert state == ModelState(1000.0, 200.0, 0.012, Rig(), hardening_ratio=0.1)
    assert state.replace(**changes) == dataclasses.replace(state, **changes)
    with pytest.raises(TypeError, match="ecoat_gpa"):
        state.replace(ecoat_gpa=1.0)

    @dataclasses.dataclass(frozen=True)
    class Checked(ModelState):
        def __post_init__(self):
            if self.tcoat_mm <= 0.0:
                raise ValueError("tcoat_mm must be > 0")

    with pytest.raises(ValueError, match="tcoat_mm"):
        Checked(1000.0, 200.0, 0.012, Rig()).replace(tcoat_mm=0.0)


def test_look_alikes_are_declared_once_and_read_both_ways(monkeypatch):
    """hardening declares membrane_bending (one moment–curvature law); each sees the other,
    no other built-in effect has one, and a plug-in's declaration is read from both sides."""
    from surrogate.effects import _base, look_alikes

    assert look_alikes("hardening") == {"membrane_bending"}
    assert look_alikes("membrane_bending") == {"hardening"}
    others = set(surrogate.available_effects()) - {"hardening", "membrane_bending"}
    assert all(look_alikes(name) == set() for name in others)

    class Stretch(surrogate.Effect):
        name = "stretch"
        look_alikes = ("tension",)

    monkeypatch.setitem(_base._REGISTRY, "stretch", Stretch())
    assert look_alikes("tension") == {"stretch"} and look_alikes("stretch") == {"tension"}
