"""The ``[measurements]`` keys, the detection of delimiter and decimal mark, and the
file-name pattern: each rule of ``surrogate/study/_formats.py`` on small texts."""

from pathlib import Path

import pytest

from surrogate import InputDataError
from surrogate.study._formats import (
    MeasurementFormat,
    NamePattern,
    detect_decimal,
    detect_delimiter,
)


@pytest.mark.parametrize(
    ("text", "delimiter"),
    [
        ("test_id,angle_deg,force_n\nT1,0,0.5\nT1,1,0.7\n", ","),
        ("test_id;angle_deg;force_n\nT1;0;0,5\nT1;1;0,7\n", ";"),
        ("Angle [deg]\tForce [N]\n0\t0,5\n1\t0,7\n", "\t"),
        ("Angle [deg]\tForce [N]\n0\t0.5\n\n1\t0.7\n\n", "\t"),  # blank lines do not count
        ('test_id,note,angle_deg,force_n\nT1,"a;b",0,0.5\n', ","),  # quoted fields
        # commas in the header's names and in the rows: ',' and ';' both split every line
        # into the same number of fields, but only ';' makes every field of the rows a number
        ("Angle, deg;Force, N\n1,5;0,5\n2,5;0,75\n", ";"),
    ],
)
def test_the_delimiter_is_detected(text, delimiter):
    assert detect_delimiter(text.splitlines(), "f.csv") == delimiter


def test_a_file_no_delimiter_fits_names_the_line_and_the_key():
    """A header written with ';' over rows exported with ','; a comma file with decimal
    commas (each row splits into more fields than the header)."""
    for text, where in (
        ("test_id;angle_deg;force_n\nT1,0,0.5\nT1,1,0.7\n", "line 2 has 1"),
        ("angle_deg,force_n\n0,0,5\n1,0,7\n", "line 2 has 3"),
    ):
        with pytest.raises(InputDataError) as caught:
            detect_delimiter(text.splitlines(), "f.csv")
        message = str(caught.value)
        assert "f.csv: cannot tell its delimiter" in message and where in message, message
        assert "set [measurements] delimiter" in message


def test_two_delimiters_that_fit_alike_are_ambiguous():
    text = "a;b,c\nx;y,z\nu;v,w\n"  # ';' and ',' both split every line into 2 text fields
    with pytest.raises(InputDataError, match="comma and semicolon both split every line into 2"):
        detect_delimiter(text.splitlines(), "f.csv")


@pytest.mark.parametrize(
    ("values", "delimiter", "decimal"),
    [
        (["0", "0,5", "1,25e-3"], ";", ","),
        (["0", "0.5", "-1.25E+3"], ";", "."),
        (["0", "1", "2"], ";", "."),  # whole numbers: either reads them alike
        (["0.5", "1.5"], ",", "."),
        (["0,5"], ",", "."),  # a comma file's decimal mark is '.' (its fields never hold ',')
    ],
)
def test_the_decimal_mark_is_detected(values, delimiter, decimal):
    assert detect_decimal(values, delimiter, "f.csv") == decimal


def test_both_decimal_marks_in_one_file_are_refused():
    with pytest.raises(InputDataError, match=r"both '0.5' and '1,5'; set \[measurements\] decimal"):
        detect_decimal(["0", "0.5", "1,5"], ";", "f.csv")


def test_the_keys_are_validated_with_the_fix():
    assert MeasurementFormat(delimiter=";", decimal=",", force_unit="mN").decimal == ","
    bad = {
        "delimiter": ({"delimiter": "|"}, "delimiter must be one of ',', ';', '\\t', got '|'"),
        "decimal": ({"decimal": ";"}, "decimal must be one of '.', ',', got ';'"),
        "comma-comma": ({"delimiter": ",", "decimal": ","}, "cannot both hold"),
        "force-unit": ({"force_unit": "newton"}, "force_unit must be one of N, mN, kN"),
        "angle-unit": ({"angle_unit": "degrees"}, "angle_unit must be one of deg, rad"),
        "encoding": ({"encoding": "utf-9"}, "encoding must be a text encoding"),
        "columns-name": ({"columns": {"Force": "F"}}, "'Force' is not a column name"),
        "columns-header": ({"columns": {"force_n": 3}}, "columns.force_n must be the file's"),
        "columns-twice": ({"columns": {"force_n": "F", "angle_deg": "F"}}, "one header to two"),
        "pattern": ({"name_pattern": "{test_id}{direction}"}, "two fields side by side"),
    }
    for keys, fragment in bad.values():
        with pytest.raises(InputDataError) as caught:
            MeasurementFormat(**keys)
        assert fragment in str(caught.value), (keys, str(caught.value))


def test_a_name_pattern_gives_typed_fields():
    pattern = NamePattern.parse("{test_id}_{direction}_{tension_n}N_{rate_deg_s}dps")
    assert pattern.fields == ("test_id", "direction", "tension_n", "rate_deg_s")
    assert pattern.match("T01_warp_12,5N_90dps") == {
        "test_id": "T01",
        "direction": "warp",
        "tension_n": 12.5,
        "rate_deg_s": 90.0,
    }
    # a test id holding the separator: the shortest text that lets the rest match
    assert pattern.match("lab_A_7_weft_0N_9.5dps")["test_id"] == "lab_A_7"
    assert pattern.match("T01_diagonal_0N_90dps") is None  # direction is warp or weft
    assert pattern.match("T01_warp_tenN_90dps") is None  # a condition's field is a number
    assert NamePattern.parse("{operator}-{test_id}").match("ann-7") == {
        "operator": "ann",
        "test_id": "7",
    }


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("plain", "must be a string with {fields}"),
        ("{test_id}_{Tension}", "field {Tension} must be test_id, a condition"),
        ("{test_id}_{force_n}", "field {force_n} must be"),
        ("{test_id}_{test_id}", "names a field twice"),
        ("{test_id}_{tension_n", "unmatched brace"),
    ],
)
def test_bad_name_patterns_say_what_is_wrong(text, fragment):
    with pytest.raises(InputDataError) as caught:
        NamePattern.parse(text)
    assert fragment in str(caught.value)


def test_the_conditions_path_is_kept():
    assert MeasurementFormat(conditions=Path("c.csv")).conditions == Path("c.csv")
