"""Measurement files that cannot be read, as a lab might export them: (id, files, what the
one line must say). ``lab.toml`` is a study reading them; the command-line tests run
``surrogate calibrate lab.toml`` on each (tests/cli/test_measurement_files.py,
tests/system/test_bad_input.py)."""

from __future__ import annotations

STUDY = """\
[study]
name = "lab"

[parameters]
ecoat_gpa = {{ low = 0.5,  high = 4.0, log = true }}
scoat_gpa = {{ low = 0.05, high = 0.4, log = true }}
tcoat_mm  = {{ low = 0.01, high = 0.1, log = true }}

[measurements]
noise_n = 0.05
{keys}
"""


def _curve(delimiter: str = ";", decimal: str = ",", force: str = "Kraft [N]") -> str:
    rows = [f"Winkel [°]{delimiter}{force}"]
    rows += [
        f"{a}{delimiter}{f}".replace(".", decimal) for a, f in ((0, 0.0), (10, 1.5), (20, 2.5))
    ]
    return "\n".join(rows) + "\n"


COLUMNS = 'columns = { angle_deg = "Winkel [°]", force_n = "Kraft [N]" }'
GOOD = _curve()
BAD_LAB_FILES = [
    (  # a line added by hand in another locale: no delimiter splits every line alike
        "delimiter-cannot-be-told",
        {"lab.toml": STUDY.format(keys=f'file = "t.csv"\n{COLUMNS}'), "t.csv": GOOD + "30,3.0\n"},
        "cannot tell its delimiter: none of comma, semicolon, tab splits",
    ),
    (  # ',' and ';' both split every line in two, with as many numbers
        "ambiguous-delimiter",
        {
            "lab.toml": STUDY.format(keys='file = "t.csv"'),
            "t.csv": "test_id;angle_deg, force_n\nA;0,0\nB;10,1\nC;20,2\n",
        },
        "comma and semicolon both split every line into 2 columns; set [measurements] delimiter",
    ),
    (
        "unknown-force-unit",
        {
            "lab.toml": STUDY.format(keys=f'file = "t.csv"\nforce_unit = "cN"\n{COLUMNS}'),
            "t.csv": GOOD,
        },
        "[measurements] force_unit must be one of N, mN, kN, gf, kgf, lbf, got 'cN'",
    ),
    (
        "glob-matches-nothing",
        {"lab.toml": STUDY.format(keys=f'file = "tests/*.csv"\n{COLUMNS}')},
        "tests/*.csv matches no file",
    ),
    (
        "test-without-conditions-row",
        {
            "lab.toml": STUDY.format(
                keys=f'file = "tests/*.csv"\nconditions = "conditions.csv"\n{COLUMNS}'
            ),
            "tests/T01.csv": GOOD,
            "tests/T02.csv": GOOD,
            "conditions.csv": "file,tension_n,direction\nT01.csv,0,warp\n",
        },
        "file 'T02.csv' has no row in the conditions table",
    ),
    (
        "non-numeric-force",
        {
            "lab.toml": STUDY.format(keys=f'file = "t.csv"\n{COLUMNS}'),
            "t.csv": GOOD.replace("2,5", "2,5?"),
        },
        "column force_n ('Kraft [N]') has a missing, NaN, inf or non-numeric value (2,5?) "
        "at line 4",
    ),
    (
        "nan-force",
        {
            "lab.toml": STUDY.format(keys=f'file = "t.csv"\n{COLUMNS}'),
            "t.csv": GOOD.replace("2,5", "NaN"),
        },
        "column force_n ('Kraft [N]') has a missing, NaN, inf or non-numeric value at line 4",
    ),
    (
        "unit-contradicts-header",
        {
            "lab.toml": STUDY.format(
                keys='file = "t.csv"\nforce_unit = "N"\n'
                'columns = { angle_deg = "Winkel [°]", force_n = "Kraft [mN]" }'
            ),
            "t.csv": _curve(force="Kraft [mN]"),
        },
        "column 'Kraft [mN]' is in mN by its name, but [measurements] force_unit = 'N'",
    ),
    (
        "file-name-not-matching-pattern",
        {
            "lab.toml": STUDY.format(
                keys=f'file = "tests/*.csv"\nname_pattern = "{{test_id}}_{{tension_n}}N"\n{COLUMNS}'
            ),
            "tests/T01_0N.csv": GOOD,
            "tests/T02.csv": GOOD,
        },
        "its name 'T02' does not match [measurements] name_pattern '{test_id}_{tension_n}N'",
    ),
]
