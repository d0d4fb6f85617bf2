"""``surrogate export``: the verified optimum from the study's storage as LS-DYNA text."""

import json

import pytest

import surrogate
from surrogate._cli import main
from surrogate.identify._verify import Verifier, open_verify_study
from surrogate.solvers._lsdyna import FIELD
from surrogate.study._spec import load_study

OPTIMUM = {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012}
OTHER = {"ecoat_gpa": 2.0, "scoat_gpa": 0.1, "tcoat_mm": 0.03}


def _verified_study(tmp_path, target):
    """A study whose verify trials hold two built-in runs (as `surrogate run` writes them)."""
    path = tmp_path / "coat.toml"
    path.write_text(f'[study]\nname = "coat"\n[targets]\nf60_n = {target!r}\n')
    spec = load_study(path)
    verifier = Verifier(
        spec, open_verify_study(spec, spec.default_storage(), heartbeat_s=None), progress=False
    )
    for point in (OTHER, OPTIMUM):
        verifier.verify([[point[n] for n in spec.space.names]], phase="test")
    return path


def test_export_writes_the_verified_optimum(tmp_path, capsys):
    target = surrogate.simulate(**OPTIMUM).f60_n
    path = _verified_study(tmp_path, target)
    result = surrogate.export(path, output=tmp_path / "coat.k")
    assert (result.ecoat_gpa, result.scoat_gpa, result.tcoat_mm) == tuple(OPTIMUM.values())
    assert result.f60_n == pytest.approx(target) and result.trial_number == 1
    assert result.parameters == pytest.approx({"ECOAT": 1000.0, "SCOAT": 200.0, "TCOAT": 0.012})
    text = (tmp_path / "coat.k").read_text()
    assert text == result.text
    lines = text.splitlines()
    card = lines[lines.index("*PARAMETER") + 2]
    fields = [card[k : k + FIELD] for k in range(0, len(card), FIELD)]
    assert [f.split() for f in fields[0::2]] == [["R", "ECOAT"], ["R", "SCOAT"], ["R", "TCOAT"]]
    assert [float(f) for f in fields[1::2]] == pytest.approx([1000.0, 200.0, 0.012])
    assert "&ECOAT    &TCOAT    &SCOAT" in text  # card 3 order: TCOAT before SCOAT

    assert main(["export", str(path), "--json", "--units", "mm-kg-ms"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert set(payload) == set(result.to_json())
    assert payload["parameters"]["ECOAT"] == pytest.approx(1.0)  # GPa in mm-kg-ms decks


def test_no_verified_point_is_one_line_exit_2(tmp_path, capsys):
    path = _verified_study(tmp_path, 500.0)  # no run comes near 500 N
    with pytest.raises(SystemExit) as exit_info:
        main(["export", str(path)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no verified point of 'coat/verify' meets" in err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--storage", "sqlite:///{tmp}/none.db"], "does not exist; run `surrogate run` first"),
        (["--output", "{tmp}/missing/coat.k"], "output folder"),
        (["--format", "abaqus"], "invalid choice"),
    ],
)
def test_bad_export_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    path = tmp_path / "coat.toml"
    path.write_text('[study]\nname = "coat"\n[targets]\nf60_n = 10.0\n')
    with pytest.raises(SystemExit) as exit_info:
        main(["export", str(path), *[a.format(tmp=tmp_path) for a in args]])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["coat.toml"]  # nothing written


@pytest.mark.parametrize(
    ("convention", "tcoat", "units"),
    [
        ("thickness", 0.012, "mm-N-s"),
        ("bending-only", -0.012, "mm-N-s"),
        ("ratio", -0.01, "mm-N-s"),  # 0.012 mm of a 1.2 mm webbing
        ("bending-only", -1.2e-5, "m-kg-s"),
        ("ratio", -0.01, "m-kg-s"),  # a ratio has no unit
    ],
)
def test_tcoat_is_written_by_the_chosen_convention_and_the_snippet_says_which(
    tmp_path, convention, tcoat, units
):
    path = _verified_study(tmp_path, surrogate.simulate(**OPTIMUM).f60_n)
    result = surrogate.export(path, tcoat=convention, units=units)
    assert result.parameters["TCOAT"] == pytest.approx(tcoat)
    assert result.tcoat_mm == pytest.approx(0.012)  # the coat itself, in mm
    assert result.parameters["ECOAT"] > 0  # a modulus in every convention
    assert f"TCOAT convention '{convention}'" in result.text
    card = result.text.splitlines()[-1]
    assert float(card[2 * FIELD + FIELD : 2 * FIELD + 2 * FIELD]) == pytest.approx(tcoat, rel=1e-6)
    assert surrogate.export(path).tcoat_convention == "thickness"  # the default


def _calibration_record(tmp_path, params, *, effects):
    """A calibration's record in the storage, as `surrogate calibrate` leaves it."""
    import optuna

    from surrogate.calibration._problem import model_label

    path = tmp_path / "measured.toml"
    (tmp_path / "m.csv").write_text("test_id,angle_deg,force_n\na,0,0\na,10,1\n")
    path.write_text('[study]\nname = "measured"\n[measurements]\nfile = "m.csv"\nnoise_n = 0.05\n')
    spec = load_study(path)
    study = optuna.create_study(
        study_name=f"measured/calibrate/{model_label(effects)}", storage=spec.default_storage()
    )
    study.set_user_attr(
        "result",
        {
            "params": params,
            "status": "converged",
            "rmse_n": 0.051,
            "noise_n": 0.05,
            "misfit": "within the noise",
        },
    )
    return path


def test_a_calibrated_coat_is_evaluated_at_the_named_conditions(tmp_path, capsys):
    params = {**OPTIMUM, "tension.k_e": 0.01, "tension.k_s": 0.005, "hardening.ratio": 0.05}
    path = _calibration_record(tmp_path, params, effects=["tension", "hardening"])
    result = surrogate.export(path, effects=["hardening", "tension"], at={"tension_n": 40.0})
    assert result.source == "calibration" and result.status == "converged"
    assert result.parameters["ECOAT"] == pytest.approx(1000.0 * 1.4)
    assert result.parameters["SCOAT"] == pytest.approx(200.0 * 1.2)
    assert result.parameters["TCOAT"] == pytest.approx(0.012)
    assert result.not_carried == ["hardening (hardening_ratio)"]
    assert "the card cannot carry: hardening (hardening_ratio)" in result.text
    assert "evaluated at tension_n=40.0" in result.text
    assert result.rmse_n == pytest.approx(0.051) and result.f60_n is None

    with pytest.raises(SystemExit) as exit_info:
        main(["export", str(path), "--effect", "tension", "--effect", "hardening"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "effect 'tension' reads the test condition tension_n" in err
    assert "--at tension_n=VALUE" in err

    assert (
        main(
            [
                "export",
                str(path),
                "--effect",
                "tension",
                "--effect",
                "hardening",
                "--at",
                "tension_n=0",
                "--json",
            ]
        )
        == 0
    )
    payload = json.loads(capsys.readouterr().out)
    assert payload["parameters"]["ECOAT"] == pytest.approx(1000.0)
    assert payload["conditions"] == {"tension_n": 0.0}


def test_export_reads_a_journal_storage(tmp_path):
    """Any storage the workers use: journal:/// as well as SQLite and PostgreSQL."""
    path = tmp_path / "coat.toml"
    path.write_text('[study]\nname = "coat"\n[targets]\nf60_n = 9.958\n')
    spec = load_study(path)
    url = f"journal:///{tmp_path / 'verify.log'}"
    verifier = Verifier(spec, open_verify_study(spec, url, heartbeat_s=None), progress=False)
    verifier.verify([[OPTIMUM[n] for n in spec.space.names]], phase="test")
    result = surrogate.export(path, storage=url)
    assert result.parameters["TCOAT"] == pytest.approx(0.012) and result.storage == url
