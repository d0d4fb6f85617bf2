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
