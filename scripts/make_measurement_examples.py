"""Write the shipped measurements again as labs export them (examples/measurements/).

    .venv/bin/python scripts/make_measurement_examples.py

Each folder holds the ten SYNTHETIC tests of ``data/measurements/webbing_tests.csv``
in one lab format, and a ``study.toml`` that reads them; the tests check that each
gives the same measurement set as the shipped file (``tests/study/test_lab_files.py``)
and ``docs/guides/measurements.md`` shows them:

- ``decimal_comma/``: ``;`` between columns, ``0,3673`` decimals (no keys needed);
- ``tab_millinewton/``: tab-separated, the force in mN under the header ``Force [mN]``;
- ``gram_force_radian/``: forces in gf and angles in radians under a lab's headers;
- ``one_file_per_test/``: one file per test as a tester writes it (``;``, decimal
  comma, a time channel), with a table of each test's conditions;
- ``file_names/``: one file per test whose name gives its conditions.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "data" / "measurements" / "webbing_tests.csv"
OUT = ROOT / "examples" / "measurements"
GRAM_FORCE_N = 9.80665e-3
STUDY = """\
# The shipped SYNTHETIC measurements (data/measurements/webbing_tests.csv), {what}.
# Written by scripts/make_measurement_examples.py; docs/guides/measurements.md.

[study]
name = "{name}"
seed = 0

[parameters]
ecoat_gpa = {{ low = 0.5,  high = 4.0, log = true }}
scoat_gpa = {{ low = 0.05, high = 0.4, log = true }}
tcoat_mm  = {{ low = 0.01, high = 0.1, log = true }}

[measurements]
{measurements}
"""


def _number(value: float, digits: int = 12) -> str:
    return f"{value:.{digits}g}"


def _comma(value: object) -> str:
    return str(value).replace(".", ",")


def _study(folder: Path, name: str, what: str, measurements: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    text = STUDY.format(name=name, what=what, measurements=measurements.strip())
    (folder / "study.toml").write_text(text, encoding="utf-8")


def decimal_comma(lines: list[str]) -> None:
    """The shipped file's own fields, ``;`` between them and ``,`` for ``.``."""
    folder = OUT / "decimal_comma"
    _study(folder, "decimal-comma", "as a European tester exports them", 'file = "tests.csv"')
    text = "".join(";".join(_comma(f) for f in line.split(",")) + "\n" for line in lines)
    (folder / "tests.csv").write_text(text, encoding="utf-8")


def tab_millinewton(table: pd.DataFrame) -> None:
    folder = OUT / "tab_millinewton"
    keys = 'file = "tests.tsv"\nforce_unit = "mN"\ncolumns = { force_n = "Force [mN]" }'
    _study(folder, "tab-millinewton", "tab-separated, forces in mN", keys)
    out = table.assign(force_n=[_number(f * 1e3) for f in table.force_n])
    out.rename(columns={"force_n": "Force [mN]"}).to_csv(
        folder / "tests.tsv", sep="\t", index=False
    )


def gram_force_radian(table: pd.DataFrame) -> None:
    folder = OUT / "gram_force_radian"
    keys = (
        'file = "tests.csv"\nforce_unit = "gf"\nangle_unit = "rad"\n'
        'columns = { angle_deg = "Rotation", force_n = "Load", temperature_c = "Temp" }'
    )
    _study(folder, "gram-force-radian", "forces in gf, angles in radians", keys)
    out = table.assign(
        angle_deg=[_number(math.radians(a)) for a in table.angle_deg],
        force_n=[_number(f / GRAM_FORCE_N) for f in table.force_n],
    )
    renames = {"angle_deg": "Rotation", "force_n": "Load", "temperature_c": "Temp"}
    out.rename(columns=renames).to_csv(folder / "tests.csv", index=False)


def one_file_per_test(table: pd.DataFrame) -> None:
    folder = OUT / "one_file_per_test"
    keys = (
        'file = "tests/*.csv"\nconditions = "conditions.csv"\n'
        'columns = { angle_deg = "Winkel [°]", force_n = "Kraft [N]" }'
    )
    _study(folder, "one-file-per-test", "one file per test with a conditions table", keys)
    (folder / "tests").mkdir(exist_ok=True)
    conditions = ["file,tension_n,direction,rate_deg_s,temperature_c"]
    for test_id, rows in table.groupby("test_id", sort=False):
        first = rows.iloc[0]
        conditions.append(
            f"{test_id}.csv,{first.tension_n:g},{first.direction},{first.rate_deg_s:g},"
            f"{first.temperature_c:g}"
        )
        lines = ["Zeit [s];Winkel [°];Kraft [N]"] + [
            f"{_comma(_number(a / first.rate_deg_s, 6))};{_comma(a)};{_comma(f)}"
            for a, f in zip(rows.angle_deg, rows.force_n, strict=True)
        ]
        (folder / "tests" / f"{test_id}.csv").write_text("\n".join(lines) + "\n", "utf-8")
    (folder / "conditions.csv").write_text("\n".join(conditions) + "\n", encoding="utf-8")


def file_names(table: pd.DataFrame) -> None:
    folder = OUT / "file_names"
    keys = (
        'file = "tests/*.csv"\nname_pattern = "{test_id}_{direction}_{tension_n}N_{rate_deg_s}dps"'
    )
    _study(folder, "file-names", "one file per test, its conditions in its name", keys)
    (folder / "tests").mkdir(exist_ok=True)
    for test_id, rows in table.groupby("test_id", sort=False):
        first = rows.iloc[0]
        name = f"{test_id}_{first.direction}_{first.tension_n:g}N_{first.rate_deg_s:g}dps.csv"
        rows[["angle_deg", "force_n", "temperature_c"]].to_csv(folder / "tests" / name, index=False)


def main() -> None:
    table = pd.read_csv(SHIPPED)
    decimal_comma(SHIPPED.read_text(encoding="utf-8").splitlines())
    tab_millinewton(table)
    gram_force_radian(table)
    one_file_per_test(table)
    file_names(table)


if __name__ == "__main__":
    main()
