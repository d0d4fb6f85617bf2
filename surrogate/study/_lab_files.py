"""Measurement files as labs export them → long tables in the product's names, N and
degrees (design.md §5).

``[measurements] file`` is one file or a glob (``tests/*.csv``, sorted by path; a
file that exists is never read as a glob). Each file is read the same way:

1. its text, in ``encoding`` (a UTF-8 byte-order mark is skipped);
2. its delimiter and decimal mark: stated, or detected (:mod:`._formats`);
3. the product's column names: ``columns`` renames the file's headers, and then
   only the columns it names and those already named in the product's style (a
   lower-case name such as ``tension_n`` or ``temperature_c``) are read, not a
   tester's ``Time [s]`` channel; a ``force_<unit>`` / ``angle_<unit>`` column such
   as ``force_mn`` is the force / angle column;
4. numbers: a missing, NaN, inf or non-numeric value is an error naming the file,
   the column and the line;
5. N and degrees (:mod:`._units`): each column in ``force_unit`` / ``angle_unit`` if
   stated, else in the unit its name states, else N and degrees; a name whose unit
   contradicts the stated one is an error;
6. its tests: a file with a ``test_id`` column holds the tests it names (the long
   format); a file without one is one test, named by the ``{test_id}`` field of
   ``name_pattern``, else by its file name without the extension;
7. its conditions: its own columns, ``name_pattern``'s fields, and its test's row
   in the ``conditions`` table (keyed by ``test_id``, or by ``file``: a one-test
   file's name); a condition given twice is an error, so is a test without a row;
   a row that matches no test is a warning.

The files are read before anything else happens: a bad one raises InputDataError,
one line, before any run, storage or cache is touched.
"""

from __future__ import annotations

import codecs
import csv
import dataclasses
import glob
import hashlib
import io
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import InputDataError
from ._conditions import CONDITIONS, NUMERIC_CONDITIONS, check_conditions
from ._formats import MeasurementFormat, check_delimiter, detect_decimal, detect_delimiter
from ._units import to_degrees, to_newtons, unit_in_name

__all__ = [
    "SourceTable",
    "measurement_sources",
    "numbers",
    "read_sources",
    "sources_sha256",
]

_MAGIC = re.compile(r"[*?[]")
_PRODUCT_NAME = re.compile(r"[a-z][a-z0-9_]*")  # test_id, tension_n, temperature_c
_QUANTITIES = (("force", "force_n", "N"), ("angle", "angle_deg", "deg"))
_ONE_TURN_DEG = 360.0
_FEW_DEG = 2.0 * np.pi  # a curve ending here in "degrees" is likely in radians
_MANY_N = 1000.0  # a bending test of webbing measures a few N: this is likely mN


@dataclass(frozen=True)
class SourceTable:
    """One measurement file, read.

    Attributes
    ----------
    path : Path
        The file.
    table : DataFrame
        Long format in the product's names: ``test_id``, ``angle_deg`` [°],
        ``force_n`` [N], conditions and covariates.
    force_unit, angle_unit : str
        The units the file was in.
    """

    path: Path
    table: pd.DataFrame
    force_unit: str
    angle_unit: str


def read_sources(file: Path, file_format: MeasurementFormat) -> tuple[list[SourceTable], list[str]]:
    """Every measurement file of ``file`` (a path or a glob), read (the module's steps),
    and the warnings about them, one line each, for the caller to give once the data is
    known to be valid."""
    used: set[str] = set()
    sources = [
        _read_file(path, file_format, used) for path in _measurement_files(file, file_format)
    ]
    notes: list[str] = []
    if file_format.conditions is not None:
        sources, notes = _join_conditions(sources, file_format, used)
    unused = [name for name, header in file_format.columns.items() if header not in used]
    if unused:
        raise InputDataError(
            f"[measurements] columns.{unused[0]} = {file_format.columns[unused[0]]!r} matches "
            "no column of the measurement files or the conditions table; fix the header"
        )
    _check_scales(sources)
    return sources, [*notes, *_odd_scales(sources, file)]


def measurement_sources(file: Path, file_format: MeasurementFormat) -> tuple[Path, ...]:
    """The files a study's measurements are read from: the measurement file(s), sorted,
    then the conditions table (if any)."""
    files = _measurement_files(file, file_format)
    return files if file_format.conditions is None else (*files, file_format.conditions)


def sources_sha256(file: Path, file_format: MeasurementFormat) -> str:
    """SHA-256 of the measurements' bytes (which data a calibration saw): of the file's
    bytes for one file; else of each file's name and SHA-256, in order."""
    paths = measurement_sources(file, file_format)
    if len(paths) == 1:
        return hashlib.sha256(paths[0].read_bytes()).hexdigest()
    digest = hashlib.sha256()
    for path in paths:
        digest.update(f"{path.name}\0{hashlib.sha256(path.read_bytes()).hexdigest()}\n".encode())
    return digest.hexdigest()


def numbers(values: pd.Series, name: str, where: str, *, decimal: str = ".") -> np.ndarray:
    """A column as floats; a missing, NaN, inf or non-numeric value is an InputDataError
    naming ``where``, the column and the line (header on line 1)."""
    text = decimal == "," and not pd.api.types.is_numeric_dtype(values)
    marked = values.str.replace(",", ".", regex=False) if text else values
    found = pd.to_numeric(marked, errors="coerce").to_numpy(float)
    bad = ~np.isfinite(found)
    if bad.any():
        row = int(np.argmax(bad))
        seen = "" if pd.isna(values.iloc[row]) else f" ({values.iloc[row]!s})"
        raise InputDataError(
            f"{where}: column {name} has a missing, NaN, inf or non-numeric value{seen} at "
            f"line {row + 2}; fix or remove the row"
        )
    return found


# -- the files -------------------------------------------------------------------------------
def _measurement_files(file: Path, file_format: MeasurementFormat) -> tuple[Path, ...]:
    """``file`` itself, or the files its glob matches (sorted, the conditions table left
    out); a glob that matches nothing is an InputDataError."""
    folder, rest = file, list[str]()
    while not folder.exists() and folder != folder.parent:
        rest.insert(0, folder.name)
        folder = folder.parent
    if not rest or not _MAGIC.search("/".join(rest)):
        return (file,)
    pattern = str(Path(glob.escape(str(folder)), *rest))
    found = sorted(
        path
        for path in map(Path, glob.glob(pattern))
        if path.is_file() and path.resolve() != _resolved(file_format.conditions)
    )
    if not found:
        raise InputDataError(
            f"[measurements] file {file} matches no file; check the pattern and the folder {folder}"
        )
    return tuple(found)


def _resolved(path: Path | None) -> Path | None:
    return None if path is None else path.resolve()


def _text(path: Path, encoding: str, what: str) -> str:
    if path.is_dir():
        raise InputDataError(
            f"{what} {path} is a folder; name a file in it, or a glob such as {path / '*.csv'}"
        )
    if not path.exists():
        raise InputDataError(f"{what} {path} does not exist; check the path")
    data = path.read_bytes()
    codec = "utf-8-sig" if codecs.lookup(encoding).name == "utf-8" else encoding
    try:
        text = data.decode(codec)
    except UnicodeDecodeError as error:
        raise InputDataError(
            f"{path}: not {encoding} text (byte {data[error.start]:#04x} at offset "
            f'{error.start}); export it as UTF-8 or set [measurements] encoding, e.g. "cp1252"'
        ) from None
    if not text.strip():
        raise InputDataError(f"{path}: no rows")
    return text


@dataclass(frozen=True)
class _Split:
    """A file's text split at its delimiter (stated or detected): the delimiter, the
    stripped header and the non-empty records after it."""

    delimiter: str
    header: tuple[str, ...]
    records: tuple[list[str], ...]

    @classmethod
    def of(cls, text: str, file_format: MeasurementFormat, where: str) -> _Split:
        lines = text.splitlines()
        if file_format.delimiter is None:
            delimiter = detect_delimiter(lines, where)
        else:
            delimiter = check_delimiter(lines, file_format.delimiter, where)
        records = [r for r in csv.reader(lines, delimiter=delimiter) if r]
        header = tuple(name.strip() for name in records[0])
        twice = sorted({name for name in header if header.count(name) > 1})
        if twice:
            raise InputDataError(f"{where}: two columns are named {twice[0]!r}; rename one")
        return cls(delimiter, header, tuple(records[1:]))

    def decimal(self, numeric: Iterable[str], file_format: MeasurementFormat, where: str) -> str:
        """The decimal mark: stated, or detected in the columns headed ``numeric``."""
        if file_format.decimal is not None:
            return file_format.decimal
        wanted = [i for i, name in enumerate(self.header) if name in set(numeric)]
        values = (row[i] for row in self.records for i in wanted if i < len(row))
        return detect_decimal(values, self.delimiter, where)

    def frame(
        self, text: str, decimal: str, what: str, where: str, **options: object
    ) -> pd.DataFrame:
        """The table, with the stripped header."""
        try:
            frame = pd.read_csv(
                io.StringIO(text), sep=self.delimiter, decimal=decimal, index_col=False, **options
            )
        except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as error:
            first = str(error).strip().splitlines()[0] if str(error).strip() else "unreadable"
            raise InputDataError(f"{what} {where} is not a readable CSV ({first})") from None
        if len(frame.columns) != len(self.header):
            raise InputDataError(
                f"{what} {where} is not a readable CSV (its lines have more fields than its "
                "header); check [measurements] delimiter"
            )
        frame.columns = list(self.header)
        empty = [c for c in frame.columns if c == "" and frame[c].isna().all()]
        frame = frame.drop(columns=empty)  # a delimiter at each line's end
        if frame.empty:
            raise InputDataError(f"{where}: no rows")
        return frame


# -- one measurement file --------------------------------------------------------------------
def _read_file(path: Path, file_format: MeasurementFormat, used: set[str]) -> SourceTable:
    where = str(path)
    text = _text(path, file_format.encoding, "measurement file")
    split = _Split.of(text, file_format, where)
    renames = _renames(split.header, file_format, where)
    used.update(renames)
    numeric = [h for h, n in renames.items() if n in ("angle_deg", "force_n", *NUMERIC_CONDITIONS)]
    numeric += [h for h in split.header if h in ("angle_deg", "force_n", *NUMERIC_CONDITIONS)]
    decimal = split.decimal(numeric, file_format, where)
    frame = split.frame(text, decimal, "measurement file", where).rename(columns=renames)
    if file_format.columns:  # a lab's own channels (``Time [s]``) are not read
        frame = frame[
            [c for c in frame.columns if c in renames.values() or _PRODUCT_NAME.fullmatch(c)]
        ]
    units = {}
    for quantity, name, default in _QUANTITIES:
        if name not in frame:
            continue  # the long format's own check names what is missing
        original = next((h for h, n in renames.items() if n == name), name)
        label = name if original == name else f"{name} ({original!r})"
        unit = _unit(original, getattr(file_format, f"{quantity}_unit"), quantity, default, where)
        convert = to_newtons if quantity == "force" else to_degrees
        frame[name] = convert(numbers(frame[name], label, where, decimal=decimal), unit)
        units[quantity] = unit
    for name in (n for n in NUMERIC_CONDITIONS if n in frame):
        frame[name] = numbers(frame[name], name, where, decimal=decimal)
    frame = _with_test(frame, path, file_format, where)
    return SourceTable(path, frame, units.get("force", "N"), units.get("angle", "deg"))


def _renames(header: tuple[str, ...], file_format: MeasurementFormat, where: str) -> dict[str, str]:
    """The file's header → the product's name, for the columns that get one."""
    renames = {}
    for name, original in file_format.columns.items():
        if original in header:
            renames[original] = name
        elif name in ("test_id", "angle_deg", "force_n"):
            raise InputDataError(
                f"{where} has no column {original!r} ([measurements] columns.{name}); its "
                f"columns are {', '.join(header)}"
            )
    for quantity, name, _ in _QUANTITIES:
        if name in renames.values():
            if name in header and name not in renames:
                raise InputDataError(
                    f"{where} has a column {name} and [measurements] columns.{name} names "
                    f"another; drop one"
                )
            continue
        named = [
            h for h in header if h.lower().startswith(f"{quantity}_") and _suffix_unit(h, quantity)
        ]
        if name not in header and len(named) > 1:
            raise InputDataError(
                f"{where} has columns {' and '.join(named)}; say which is the {quantity} with "
                f"[measurements] columns.{name}"
            )
        if name not in header and named:
            renames[named[0]] = name
    return renames


def _suffix_unit(header: str, quantity: str) -> str | None:
    return unit_in_name(header, quantity) if "[" not in header and "(" not in header else None


def _unit(original: str, stated: str | None, quantity: str, default: str, where: str) -> str:
    """The unit of a force or angle column: stated, else its name's, else ``default``."""
    try:
        named = unit_in_name(original, quantity)
    except InputDataError as error:
        raise InputDataError(f"{where}: {error}") from None
    if stated is not None and named is not None and stated != named:
        raise InputDataError(
            f"{where}: column {original!r} is in {named} by its name, but [measurements] "
            f"{quantity}_unit = {stated!r}; correct one of them"
        )
    return stated or named or default


def _with_test(
    frame: pd.DataFrame, path: Path, file_format: MeasurementFormat, where: str
) -> pd.DataFrame:
    """The file's table with its test (``test_id``) and ``name_pattern``'s fields."""
    pattern = file_format.pattern
    fields = {} if pattern is None else pattern.match(path.stem)
    if fields is None:
        assert pattern is not None
        raise InputDataError(
            f"{where}: its name {path.stem!r} does not match [measurements] name_pattern "
            f"{pattern.text!r}; rename the file or fix the pattern"
        )
    twice = [name for name in fields if name in frame.columns]
    if twice:
        raise InputDataError(
            f"{where}: {twice[0]} is both a column of the file and a field of [measurements] "
            "name_pattern; keep one"
        )
    _check_fields(fields, f"{where} (by its name)")
    if "test_id" not in frame.columns:
        _check_one_curve(frame, where)
        frame.insert(0, "test_id", str(fields.pop("test_id", path.stem)))
    return frame.assign(**fields) if fields else frame


def _check_fields(fields: dict[str, object], where: str) -> None:
    try:
        check_conditions({k: v for k, v in fields.items() if k in CONDITIONS})
    except InputDataError as error:
        raise InputDataError(f"{where}: {error}") from None


def _check_one_curve(frame: pd.DataFrame, where: str) -> None:
    if "angle_deg" not in frame:
        return
    angles = frame.angle_deg.to_numpy(float)
    falls = np.flatnonzero(np.diff(angles) <= 0.0)
    if falls.size:
        raise InputDataError(
            f"{where} has no test_id column, so it is one test, but its angles do not rise at "
            f"line {falls[0] + 3}; add a test_id column (many tests in one file) or give one "
            "file per test"
        )


# -- the conditions table --------------------------------------------------------------------
def _join_conditions(
    sources: list[SourceTable], file_format: MeasurementFormat, used: set[str]
) -> tuple[list[SourceTable], list[str]]:
    """Each source with its tests' rows of the conditions table, and the warning of rows
    without a test, if any; a test without a row is an InputDataError."""
    assert file_format.conditions is not None
    key, table = _conditions_table(file_format.conditions, file_format, used)
    where_table = str(file_format.conditions)
    rows = table.set_index(key)
    joined, matched = [], set()
    for source in sources:
        ids = _keys(source, key)
        missing = [i for i in dict.fromkeys(ids) if i not in rows.index]
        if missing:
            raise InputDataError(
                f"{source.path}: {'file' if key == 'file' else 'test'} {missing[0]!r} has no row "
                f"in the conditions table {where_table}; add a row with {key} = {missing[0]!r}"
            )
        twice = [c for c in rows.columns if c in source.table.columns]
        if twice:
            raise InputDataError(
                f"{source.path}: {twice[0]} is both in the file and in the conditions table "
                f"{where_table}; keep one"
            )
        extra = {c: ids.map(rows[c]).to_numpy() for c in rows.columns}
        joined.append(dataclasses.replace(source, table=source.table.assign(**extra)))
        matched.update(ids)
    unmatched = [i for i in rows.index if i not in matched]
    if not unmatched:
        return joined, []
    return joined, [
        f"{where_table}: {len(unmatched)} row(s) match no measurement file (the first: "
        f"{key} = {unmatched[0]!r}); they are not read"
    ]


def _keys(source: SourceTable, key: str) -> pd.Series:
    """Each row's key into the conditions table: its file's name or its test_id (text)."""
    if key == "file":
        return pd.Series(source.path.name, index=source.table.index)
    return source.table.test_id.astype(str)


def _conditions_table(
    path: Path, file_format: MeasurementFormat, used: set[str]
) -> tuple[str, pd.DataFrame]:
    """(its key column, the table) of a conditions table, its values checked."""
    where = str(path)
    text = _text(path, file_format.encoding, "conditions table")
    renames = {h: n for n, h in file_format.columns.items()}
    split = _Split.of(text, file_format, where)
    used.update(h for h in split.header if h in renames)
    numeric = [h for h in split.header if renames.get(h, h) in NUMERIC_CONDITIONS]
    decimal = split.decimal(numeric, file_format, where)
    as_text = {
        h: str for h in split.header if renames.get(h, h) in ("test_id", "file", "direction")
    }
    table = split.frame(text, decimal, "conditions table", where, dtype=as_text)
    table = table.rename(columns=renames)
    key = next((k for k in ("file", "test_id") if k in table), None)
    if key is None:
        raise InputDataError(
            f"{where}: a conditions table needs a test_id or a file column (the file name of "
            "each one-test file); add one"
        )
    twice = table[key][table[key].duplicated()]
    if len(twice):
        raise InputDataError(f"{where}: {key} {twice.iloc[0]!r} has two rows; keep one")
    for name in (n for n in NUMERIC_CONDITIONS if n in table):
        table[name] = numbers(table[name], name, where, decimal=decimal)
    for direction in table.get("direction", pd.Series(dtype=str)).unique():
        _check_fields({"direction": direction}, where)
    return key, table.drop(columns=[k for k in ("file", "test_id") if k != key and k in table])


# -- plausibility of the units ---------------------------------------------------------------
def _check_scales(sources: list[SourceTable]) -> None:
    """Angles beyond a turn of the fixture are an error (the unit is likely wrong)."""
    for source in sources:
        if "angle_deg" not in source.table:
            continue
        top = float(source.table.angle_deg.abs().max())
        if top > _ONE_TURN_DEG:
            unit = "" if source.angle_unit == "deg" else f" (from {source.angle_unit})"
            raise InputDataError(
                f"{source.path}: the angles reach {top:g}°{unit}, more than a turn of the "
                "fixture; check the angle column and [measurements] angle_unit"
            )


def _odd_scales(sources: list[SourceTable], file: Path) -> list[str]:
    """Warnings of curves that end at a few "degrees" or reach thousands of "N" (the unit
    is likely radians or mN)."""
    notes = []
    in_deg = [s.table.angle_deg.max() for s in sources if "angle_deg" in s.table]
    if in_deg and all(s.angle_unit == "deg" for s in sources):
        if (top := float(max(in_deg))) <= _FEW_DEG:
            notes.append(
                f"{file}: the angles end at {top:g}°: if they are radians, set "
                '[measurements] angle_unit = "rad"'
            )
    in_n = [s.table.force_n.max() for s in sources if "force_n" in s.table]
    if in_n and all(s.force_unit == "N" for s in sources):
        if (top := float(max(in_n))) > _MANY_N:
            notes.append(
                f"{file}: the forces reach {top:g} N, far above a bending test's few N: if "
                'they are mN, set [measurements] force_unit = "mN"'
            )
    return notes
