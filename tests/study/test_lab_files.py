"""Measurement files as labs export them (``surrogate/study/_lab_files.py``): each format on
real files, the same measurement set as the shipped long file, and a one-line error for
each file that cannot be read."""

import hashlib
import re
import warnings

import numpy as np
import pandas as pd
import pytest

from surrogate import InputDataError, InputDataWarning
from surrogate.calibration._calibrate import data_hash
from surrogate.study._measurements import load_measurements
from surrogate.study._spec import load_study
from tests.conftest import REPO

EXAMPLES = REPO / "examples" / "measurements"
SHIPPED = REPO / "data" / "measurements" / "webbing_tests.csv"
STUDY = """\
[study]
name = "lab"

[parameters]
ecoat_gpa = { low = 0.5,  high = 4.0, log = true }
scoat_gpa = { low = 0.05, high = 0.4, log = true }
tcoat_mm  = { low = 0.01, high = 0.1, log = true }

[measurements]
"""
CURVE = [(0, 0.0), (10, 1.5), (20, 2.5), (30, 3.0)]  # (angle_deg, force_n)


def _load(folder, keys, files):
    """The measurement set of a study in ``folder`` with ``keys`` under [measurements]."""
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        data = text if isinstance(text, bytes) else text.encode()
        (folder / name).write_bytes(data)
    (folder / "study.toml").write_text(STUDY + keys, encoding="utf-8")
    spec = load_study(folder / "study.toml")
    return load_measurements(spec.measurements_file, file_format=spec.measurement_format)


def _refused(folder, keys, files):
    with pytest.raises(InputDataError) as caught:
        _load(folder, keys, files)
    message = str(caught.value)
    assert "\n" not in message
    return message


def _rows(delimiter=",", decimal=".", header=("angle_deg", "force_n"), scale=1.0, lead=()):
    lines = [delimiter.join(header)]
    for angle, force in CURVE:
        fields = [*lead, f"{angle:g}", f"{force * scale:g}".replace(".", decimal)]
        lines.append(delimiter.join(fields))
    return "\n".join(lines) + "\n"


# -- the shipped examples: the shipped set in five lab formats --------------------------------
@pytest.fixture(scope="module")
def shipped():
    return load_measurements(SHIPPED)


@pytest.mark.parametrize(
    "case",
    ["decimal_comma", "tab_millinewton", "gram_force_radian", "one_file_per_test", "file_names"],
)
def test_each_lab_format_gives_the_shipped_measurement_set(case, shipped):
    """The examples (docs/guides/measurements.md) hold the shipped tests; converted values
    are printed with 12 significant digits, hence rtol 1e-10."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # none of them is odd
        spec = load_study(EXAMPLES / case / "study.toml")
        data = load_measurements(spec.measurements_file, file_format=spec.measurement_format)
    assert (data.conditions, data.covariates) == (shipped.conditions, shipped.covariates)
    curves = data.curves[list(shipped.curves.columns)]  # a name's fields come last
    pd.testing.assert_frame_equal(curves, shipped.curves, rtol=1e-10)
    pd.testing.assert_frame_equal(data.tests, shipped.tests, rtol=1e-10)
    assert data.noise_n == pytest.approx(shipped.noise_n, rel=1e-9)
    assert data.noise_dof == shipped.noise_dof


def test_the_decimal_comma_example_is_the_shipped_file_exactly(shipped):
    """The same digits with ';' and ',': nothing converted, so nothing differs."""
    data = load_measurements(EXAMPLES / "decimal_comma" / "tests.csv")
    pd.testing.assert_frame_equal(data.curves, shipped.curves, check_exact=True)
    assert data.noise_n == shipped.noise_n


def test_the_examples_are_what_the_script_writes(tmp_path, monkeypatch):
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make", REPO / "scripts" / "make_measurement_examples.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "OUT", tmp_path)
    module.main()
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert written == sorted(p.relative_to(EXAMPLES) for p in EXAMPLES.rglob("*") if p.is_file())
    for path in written:
        assert (tmp_path / path).read_bytes() == (EXAMPLES / path).read_bytes(), path


GUIDE = REPO / "docs" / "guides" / "measurements.md"


def test_the_guides_file_blocks_are_what_the_files_hold():
    """A block of docs/guides/measurements.md whose first line names a file shows lines of
    that file, as they are."""
    blocks = re.findall(r"```(?:text|toml)\n# (examples/\S+)\n(.*?)```", GUIDE.read_text(), re.S)
    assert len(blocks) >= 10
    for name, shown in blocks:
        lines, held = shown.splitlines(), (REPO / name).read_text(encoding="utf-8").splitlines()
        starts = [i for i, line in enumerate(held) if line == lines[0]]
        assert any(held[i : i + len(lines)] == lines for i in starts), name


# -- formats ---------------------------------------------------------------------------------
def test_tab_separated_millinewton_by_the_column_name(tmp_path):
    """``force_mn``: the product's own style of a unit in a name; no key needed."""
    text = _rows("\t", header=("test_id", "angle_deg", "force_mn"), scale=1e3, lead=("T1",))
    data = _load(tmp_path, 'file = "t.tsv"\n', {"t.tsv": text})
    np.testing.assert_allclose(data.curves.force_n, [f for _, f in CURVE], rtol=1e-15)
    assert list(data.curves.columns) == ["test_id", "angle_deg", "force_n"]


@pytest.mark.parametrize(
    ("unit", "per_n"), [("mN", 1e3), ("kN", 1e-3), ("gf", 1 / 9.80665e-3), ("lbf", 1 / 4.4482216)]
)
def test_a_stated_force_unit_is_converted_to_newtons(tmp_path, unit, per_n):
    text = _rows(";", ",", header=("test_id", "angle_deg", "Kraft"), scale=per_n, lead=("T1",))
    keys = f'file = "t.csv"\nforce_unit = "{unit}"\ncolumns = {{ force_n = "Kraft" }}\n'
    data = _load(tmp_path, keys, {"t.csv": text})
    # the file holds 6 significant digits (f"{:g}")
    np.testing.assert_allclose(data.curves.force_n, [f for _, f in CURVE], rtol=1e-5)


def test_radians_are_converted_to_degrees(tmp_path):
    lines = ["test_id,angle_rad,force_n"] + [f"T1,{np.radians(a):.15g},{f}" for a, f in CURVE]
    data = _load(tmp_path, 'file = "t.csv"\n', {"t.csv": "\n".join(lines)})
    np.testing.assert_allclose(data.curves.angle_deg, [a for a, _ in CURVE], rtol=1e-14)
    keys = 'file = "t.csv"\nangle_unit = "rad"\ncolumns = { angle_deg = "phi" }\n'
    text = "\n".join(lines).replace("angle_rad", "phi")
    data = _load(tmp_path, keys, {"t.csv": text})
    np.testing.assert_allclose(data.curves.angle_deg, [a for a, _ in CURVE], rtol=1e-14)


def test_a_byte_order_mark_and_a_windows_encoding(tmp_path):
    text = _rows(";", ",", header=("test_id", "Winkel [°]", "Kraft [N]"), lead=("T1",))
    keys = 'file = "t.csv"\ncolumns = { angle_deg = "Winkel [°]", force_n = "Kraft [N]" }\n'
    bom = _load(tmp_path, keys, {"t.csv": b"\xef\xbb\xbf" + text.encode()})
    assert list(bom.curves.columns) == ["test_id", "angle_deg", "force_n"]
    windows = {"t.csv": text.encode("cp1252")}
    assert "not utf-8 text (byte 0xb0" in _refused(tmp_path, keys, windows)
    assert 'encoding, e.g. "cp1252"' in _refused(tmp_path, keys, windows)
    data = _load(tmp_path, keys + 'encoding = "cp1252"\n', windows)
    pd.testing.assert_frame_equal(data.curves, bom.curves)


def test_a_stated_delimiter_is_checked_and_a_trailing_one_is_no_column(tmp_path):
    text = _rows(";", ",", header=("test_id", "angle_deg", "force_n"), lead=("T1",))
    trailing = text.replace("\n", ";\n")
    data = _load(tmp_path, 'file = "t.csv"\ndelimiter = ";"\ndecimal = ","\n', {"t.csv": trailing})
    assert list(data.curves.columns) == ["test_id", "angle_deg", "force_n"]
    message = _refused(tmp_path, 'file = "t.csv"\ndelimiter = "\\t"\n', {"t.csv": text})
    assert (
        "delimiter = '\\t' does not split it into columns (split at each tab, the header is "
        "one column); check the key (or leave it out: it is detected)"
    ) in message


def test_a_testers_channels_are_not_read_once_columns_are_named(tmp_path):
    lines = ["Zeit [s];Weg [mm];Winkel [°];Kraft [N];temperature_c"] + [
        f"{a / 90:g};{a / 10:g};{a};{str(f).replace('.', ',')};21,5" for a, f in CURVE
    ]
    keys = 'file = "T1.csv"\ncolumns = { angle_deg = "Winkel [°]", force_n = "Kraft [N]" }\n'
    data = _load(tmp_path, keys, {"T1.csv": "\n".join(lines)})
    assert list(data.curves.columns) == ["test_id", "angle_deg", "force_n", "temperature_c"]
    assert data.covariates == ("temperature_c",) and list(data.tests.test_id) == ["T1"]


def test_without_columns_a_channel_is_refused_with_the_fix(tmp_path):
    lines = ["time_s,angle_deg,force_n"] + [f"{a / 90:g},{a},{f}" for a, f in CURVE]
    message = _refused(tmp_path, 'file = "T1.csv"\n', {"T1.csv": "\n".join(lines)})
    assert "time_s changes within test 'T1'" in message
    assert "read only your columns with [measurements] columns" in message


def test_one_file_per_test_with_a_conditions_table_by_test_id(tmp_path):
    files = {
        "runs/A1.csv": _rows(";", ","),
        "runs/A2.csv": _rows(";", ","),
        "runs/B1.csv": _rows(";", ",", scale=2.0),
        # beside the tests and matched by the glob: never read as one
        "runs/conditions.csv": "test_id;tension_n;direction;operator\nA1;0;warp;ann\n"
        "A2;0;warp;bob\nB1;12,5;weft;ann\n",
    }
    keys = 'file = "runs/*.csv"\nconditions = "runs/conditions.csv"\n'
    data = _load(tmp_path, keys, files)
    assert list(data.tests.test_id) == ["A1", "A2", "B1"]
    assert data.conditions == ("tension_n", "direction") and data.covariates == ("operator",)
    assert data.conditions_of("B1") == {"tension_n": 12.5, "direction": "weft"}
    assert data.noise_n == 0.0  # A1 and A2 are identical replicates


def test_long_files_of_a_glob_and_a_conditions_table_for_their_tests(tmp_path):
    """Several long files (one a day, say): each keeps its test ids."""
    files = {
        "day1.csv": _rows(lead=("T1",), header=("test_id", "angle_deg", "force_n")),
        "day2.csv": _rows(lead=("T2",), header=("test_id", "angle_deg", "force_n")),
        "cond.csv": "test_id,tension_n\nT1,0\nT2,10\n",
    }
    data = _load(tmp_path, 'file = "day*.csv"\nconditions = "cond.csv"\n', files)
    assert data.conditions_of("T2") == {"tension_n": 10.0}


def test_conditions_from_the_file_name(tmp_path):
    files = {
        "tests/W-01_warp_0N.csv": _rows("\t"),
        "tests/W-02_warp_0N.csv": _rows("\t"),
        "tests/F-01_weft_12,5N.csv": _rows("\t"),
    }
    keys = 'file = "tests/*.csv"\nname_pattern = "{test_id}_{direction}_{tension_n}N"\n'
    data = _load(tmp_path, keys, files)
    assert sorted(data.tests.test_id) == ["F-01", "W-01", "W-02"]
    assert data.conditions_of("F-01") == {"tension_n": 12.5, "direction": "weft"}


def test_a_file_name_without_test_id_field_names_the_test(tmp_path):
    keys = 'file = "tests/*.csv"\nname_pattern = "{operator}_{tension_n}N"\n'
    files = {"tests/ann_0N.csv": _rows(), "tests/bob_10N.csv": _rows()}
    data = _load(tmp_path, keys, files)
    assert list(data.tests.test_id) == ["ann_0N", "bob_10N"]
    assert list(data.tests.operator) == ["ann", "bob"]


def test_a_conditions_row_without_a_test_is_a_warning(tmp_path):
    files = {"t/A.csv": _rows(), "c.csv": "file,tension_n\nA.csv,0\nB.csv,5\n"}
    with pytest.warns(InputDataWarning, match=r"1 row\(s\) match no measurement file.*'B.csv'"):
        _load(tmp_path, 'file = "t/*.csv"\nconditions = "c.csv"\n', files)


def test_radian_looking_degrees_and_millinewton_looking_newtons_are_warnings(tmp_path):
    small = "\n".join(["angle_deg,force_n"] + [f"{np.radians(a):g},{f}" for a, f in CURVE])
    with pytest.warns(InputDataWarning, match='if they are radians, set .*angle_unit = "rad"'):
        _load(tmp_path, 'file = "T1.csv"\n', {"T1.csv": small})
    with pytest.warns(InputDataWarning, match='if they are mN, set .*force_unit = "mN"'):
        _load(tmp_path, 'file = "T1.csv"\n', {"T1.csv": _rows(scale=1e3)})


def test_one_file_gives_the_hash_of_its_bytes_and_a_glob_of_every_file(tmp_path):
    """The single file's hash is what calibrations stored before (its bytes' SHA-256)."""
    (tmp_path / "t").mkdir()
    (tmp_path / "m.csv").write_text(_rows(lead=("T1",), header=("test_id", "angle_deg", "force_n")))
    (tmp_path / "study.toml").write_text(STUDY + 'file = "m.csv"\n')
    spec = load_study(tmp_path / "study.toml")
    assert data_hash(spec) == hashlib.sha256((tmp_path / "m.csv").read_bytes()).hexdigest()
    for name in ("A", "B"):
        (tmp_path / "t" / f"{name}.csv").write_text(_rows())
    (tmp_path / "study.toml").write_text(STUDY + 'file = "t/*.csv"\n')
    spec = load_study(tmp_path / "study.toml")
    before = data_hash(spec)
    (tmp_path / "t" / "B.csv").write_text(_rows(scale=2.0))
    assert data_hash(spec) != before


# -- files that cannot be read: one line naming the file, what is wrong and the fix --------------
def test_bad_files_are_refused_with_one_line(tmp_path):
    semicolon = _rows(";", ",", header=("test_id", "angle_deg", "force_n"), lead=("T1",))
    cases = {
        "undetectable delimiter": (
            'file = "t.csv"\n',
            {"t.csv": "test_id;angle_deg;force_n\nT1,0,0.5\nT1,1,0.7\nT1,2,0.8\n"},
            "t.csv: cannot tell its delimiter",
        ),
        "both decimal marks": (
            'file = "t.csv"\n',
            {"t.csv": semicolon.replace("1,5", "1.5")},
            "cannot tell its decimal mark: it holds both '1.5' and '2,5'",
        ),
        "non-numeric force": (
            'file = "t.csv"\n',
            {"t.csv": semicolon.replace("2,5", "2,5 N")},
            "t.csv: column force_n has a missing, NaN, inf or non-numeric value (2,5 N) at line 4",
        ),
        "text in a condition": (
            'file = "t.csv"\n',
            {
                "t.csv": "test_id;angle_deg;force_n;tension_n\n"
                + "".join(f"T1;{a};0,5;{'12,5 N' if a == 20 else '12,5'}\n" for a in (0, 10, 20))
            },
            "column tension_n has a missing, NaN, inf or non-numeric value (12,5 N) at line 4",
        ),
        "NaN force": (
            'file = "t.csv"\n',
            {"t.csv": semicolon.replace("2,5", "NaN")},
            "column force_n has a missing, NaN, inf or non-numeric value at line 4",
        ),
        "mapped header missing": (
            'file = "t.csv"\ncolumns = { force_n = "Force [N]" }\n',
            {"t.csv": semicolon},
            "t.csv has no column 'Force [N]' ([measurements] columns.force_n); its columns "
            "are test_id, angle_deg, force_n",
        ),
        "mapped condition nowhere": (
            'file = "t.csv"\ncolumns = { tension_n = "Pretension [N]" }\n',
            {"t.csv": semicolon},
            "columns.tension_n = 'Pretension [N]' matches no column",
        ),
        "name contradicts unit": (
            'file = "t.csv"\nforce_unit = "N"\ncolumns = { force_n = "Force [mN]" }\n',
            {"t.csv": semicolon.replace(";force_n", ";Force [mN]")},
            "column 'Force [mN]' is in mN by its name, but [measurements] force_unit = 'N'",
        ),
        "a column without unit": (
            'file = "t.csv"\nangle_unit = "rad"\n',
            {"t.csv": semicolon.replace("angle_deg", "angle")},
            "column 'angle' has no unit; name it 'angle_deg'",  # the long format's refusal
        ),
        "degrees read as radians": (
            'file = "t.csv"\nangle_unit = "rad"\ncolumns = { angle_deg = "phi" }\n',
            {"t.csv": semicolon.replace("angle_deg", "phi")},
            "the angles reach 1718.87° (from rad), more than a turn",
        ),
        "glob matching nothing": (
            'file = "tests/*.csv"\n',
            {"tests/readme.txt": "not a test"},
            "tests/*.csv matches no file; check the pattern and the folder",
        ),
        "test without conditions row": (
            'file = "t/*.csv"\nconditions = "c.csv"\n',
            {"t/A.csv": _rows(), "t/B.csv": _rows(), "c.csv": "file,tension_n\nA.csv,0\n"},
            "t/B.csv: file 'B.csv' has no row in the conditions table",
        ),
        "conditions table without key": (
            'file = "t/*.csv"\nconditions = "c.csv"\n',
            {"t/A.csv": _rows(), "c.csv": "name,tension_n\nA.csv,0\n"},
            "needs a test_id or a file column",
        ),
        "condition given twice": (
            'file = "t/*.csv"\nconditions = "c.csv"\nname_pattern = "{test_id}_{tension_n}N"\n',
            {"t/A_0N.csv": _rows(), "c.csv": "test_id,tension_n\nA,0\n"},
            "tension_n is both in the file and in the conditions table",
        ),
        "bad direction in table": (
            'file = "t/*.csv"\nconditions = "c.csv"\n',
            {"t/A.csv": _rows(), "c.csv": "file,direction\nA.csv,bias\n"},
            "c.csv: direction must be warp or weft, got 'bias'",
        ),
        "name not matching pattern": (
            'file = "t/*.csv"\nname_pattern = "{test_id}_{tension_n}N"\n',
            {"t/A_0N.csv": _rows(), "t/B.csv": _rows()},
            "t/B.csv: its name 'B' does not match [measurements] name_pattern",
        ),
        "one test twice": (
            'file = "day*.csv"\n',
            {
                "day1.csv": _rows(lead=("T1",), header=("test_id", "angle_deg", "force_n")),
                "day2.csv": _rows(lead=("T1",), header=("test_id", "angle_deg", "force_n")),
            },
            "day2.csv: test 'T1' is also in",
        ),
        "long file without test_id": (
            'file = "t.csv"\n',
            {"t.csv": _rows() + "".join(f"{a},{f}\n" for a, f in CURVE)},
            "has no test_id column, so it is one test, but its angles do not rise at line 6",
        ),
        "a folder": ('file = "t"\n', {"t/A.csv": _rows()}, "is a folder; name a file in it"),
    }
    for name, (keys, files, fragment) in cases.items():
        folder = tmp_path / name.replace(" ", "-")
        folder.mkdir()
        message = _refused(folder, keys, files)
        assert fragment in message, (name, message)


def test_study_keys_of_measurements_are_validated(tmp_path):
    cases = {
        'file = "t.csv"\nsep = ";"\n': "unknown in [measurements] 'sep'; allowed: file, noise_n",
        'force_unit = "mN"\n': "[measurements] force_unit is set but no file",
        'file = "t.csv"\nforce_unit = "lb"\n': "[measurements] force_unit must be one of N, mN",
        'file = "t.csv"\nconditions = "../../../c.csv"\n': "leaves the project folder",
        'file = "t.csv"\ndelimiter = ","\ndecimal = ","\n': "cannot both hold",
        'file = "t.csv"\nname_pattern = "{id}_{id}"\n': "names a field twice",
    }
    for keys, fragment in cases.items():
        (tmp_path / "study.toml").write_text(STUDY + keys, encoding="utf-8")
        with pytest.raises(InputDataError) as caught:
            load_study(tmp_path / "study.toml")
        assert fragment in str(caught.value), (keys, str(caught.value))
