"""How a lab's measurement files are read: the ``[measurements]`` keys as a frozen
:class:`MeasurementFormat`, the detection of delimiter and decimal mark, and the
file-name pattern that gives a test's conditions.

Plain Python, no pandas: the study file is validated with it before anything is
read. The rules, each in one function here:

- **delimiter** (:func:`detect_delimiter`): of ``,``, ``;`` and tab, the one that
  splits the header and every non-empty line into the same number (≥ 2) of fields;
  if several do, the one that makes the largest share of the data fields numbers;
  still a tie, or none: an error asking for ``delimiter``.
- **decimal mark** (:func:`detect_decimal`): ``.`` in a comma-delimited file (a file
  cannot use ``,`` for both); otherwise ``,`` if the numeric columns hold numbers
  such as ``0,123`` and none such as ``0.123``, ``.`` in the reverse case or with
  whole numbers only; both kinds: an error asking for ``decimal``. No thousands
  separators.
- **file names** (:class:`NamePattern`): ``name_pattern`` such as
  ``"{test_id}_{direction}_{tension_n}N"`` must match a file's whole name without
  its extension; text between fields is literal. A numeric condition's field
  (``tension_n``, ``rate_deg_s``, ``bending_length_mm``, ``free_length_mm``,
  ``width_mm``) matches a number (``20``, ``12.5`` or ``12,5``), ``direction``
  matches ``warp`` or ``weft``, any other field (``test_id``, a covariate such as
  ``operator``) the shortest text that lets the rest match.
"""

from __future__ import annotations

import codecs
import csv
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._errors import InputDataError
from ._conditions import CONDITIONS, NUMERIC_CONDITIONS
from ._units import check_unit

__all__ = [
    "COLUMN_NAMES",
    "DECIMALS",
    "DELIMITERS",
    "MeasurementFormat",
    "NamePattern",
    "check_delimiter",
    "detect_decimal",
    "detect_delimiter",
]

DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab"}
DECIMALS = (".", ",")
COLUMN_NAMES = ("test_id", "angle_deg", "force_n", *CONDITIONS)
"""The product's own column names (a ``columns`` mapping may also name covariates)."""

_NUMBER = {
    ".": re.compile(r"[-+]?(\d+\.\d*|\.\d+)([eE][-+]?\d+)?"),
    ",": re.compile(r"[-+]?(\d+,\d*|,\d+)([eE][-+]?\d+)?"),
}
_WHOLE = re.compile(r"[-+]?\d+([eE][-+]?\d+)?")
_FIELD = re.compile(r"\{([^{}]*)\}")
_FIELD_NAME = re.compile(r"[a-z][a-z0-9_]*")
_FIELD_REGEX = {
    **dict.fromkeys(NUMERIC_CONDITIONS, r"[-+]?\d+(?:[.,]\d+)?"),
    "direction": "warp|weft",
}


@dataclass(frozen=True)
class NamePattern:
    """A ``name_pattern``: the fields a file's name gives (see the module's rules).

    Attributes
    ----------
    text : str
        The pattern as written, e.g. ``"{test_id}_{direction}_{tension_n}N"``.
    fields : tuple of str
        Its field names, in order.
    """

    text: str
    fields: tuple[str, ...]
    _regex: re.Pattern[str] = field(repr=False, compare=False)

    @classmethod
    def parse(cls, text: object) -> NamePattern:
        """The pattern of ``text``, or an InputDataError naming what is wrong."""
        if not isinstance(text, str) or not _FIELD.search(text):
            raise InputDataError(
                'name_pattern must be a string with {fields}, e.g. "{test_id}_{tension_n}N", '
                f"got {text!r}"
            )
        parts = _FIELD.split(text)  # literal, field, literal, field, …, literal
        literals, names = parts[0::2], parts[1::2]
        _check_fields(text, literals, names)
        regex = "".join(
            re.escape(literal) if i % 2 == 0 else f"(?P<{literal}>{_field_regex(literal)})"
            for i, literal in enumerate(parts)
        )
        return cls(text, tuple(names), re.compile(regex))

    def match(self, stem: str) -> dict[str, Any] | None:
        """The fields of a file name without its extension (numbers as floats), or None."""
        found = self._regex.fullmatch(stem)
        if found is None:
            return None
        return {
            name: float(value.replace(",", ".")) if name in NUMERIC_CONDITIONS else value
            for name, value in found.groupdict().items()
        }


def _field_regex(name: str) -> str:
    return _FIELD_REGEX.get(name, ".+?")


def _check_fields(text: str, literals: list[str], names: list[str]) -> None:
    if any("{" in part or "}" in part for part in literals):
        raise InputDataError(
            f"name_pattern {text!r} has an unmatched brace; write fields as {{name}}"
        )
    for name in names:
        if not _FIELD_NAME.fullmatch(name) or name in ("angle_deg", "force_n"):
            raise InputDataError(
                f"name_pattern {text!r}: field {{{name}}} must be test_id, a condition "
                f"({', '.join(CONDITIONS)}) or a lower-case covariate name such as operator"
            )
    if len(set(names)) != len(names):
        raise InputDataError(f"name_pattern {text!r} names a field twice")
    if any(not literal for literal in literals[1:-1]):
        raise InputDataError(
            f"name_pattern {text!r} puts two fields side by side; separate them, e.g. with '_'"
        )


@dataclass(frozen=True)
class MeasurementFormat:
    """How the measurement files of a study are read: the ``[measurements]`` keys
    besides ``file`` and ``noise_n``, validated on construction.

    Parameters
    ----------
    delimiter : {",", ";", "\\t"} or None
        Between columns; None: detected in each file.
    decimal : {".", ","} or None
        The decimal mark; None: detected in each file.
    encoding : str
        The files' text encoding (a UTF-8 byte-order mark is skipped).
    force_unit : str or None
        Unit of the force column (a key of ``FORCE_UNITS``); None: the unit its name
        states (``force_mn``, ``Force [mN]``), else N.
    angle_unit : {"deg", "rad"} or None
        Unit of the angle column; None: the unit its name states, else degrees.
    columns : mapping of str to str
        The product's column name (``angle_deg``, ``force_n``, ``test_id``, a
        condition or a covariate such as ``temperature_c``) → the file's header for
        it, e.g. ``{"force_n": "Force [mN]"}``. Given, a measurement file's other
        columns are read only if named in the product's style (lower case, such as
        ``temperature_c``): a tester's ``Time [s]`` channel is not.
    conditions : Path or None
        A table of each test's conditions, keyed by ``test_id`` or by ``file`` (the
        file name of a one-test file).
    name_pattern : str or None
        The fields a file's name gives (:class:`NamePattern`).
    """

    delimiter: str | None = None
    decimal: str | None = None
    encoding: str = "utf-8"
    force_unit: str | None = None
    angle_unit: str | None = None
    columns: Mapping[str, str] = field(default_factory=dict)
    conditions: Path | None = None
    name_pattern: str | None = None

    def __post_init__(self) -> None:
        _check_choice("delimiter", self.delimiter, DELIMITERS)
        _check_choice("decimal", self.decimal, DECIMALS)
        if self.delimiter == "," and self.decimal == ",":
            raise InputDataError(
                'delimiter = "," and decimal = "," cannot both hold: a comma cannot separate '
                'columns and decimals; the file is likely delimiter = ";"'
            )
        _check_encoding(self.encoding)
        if self.force_unit is not None:
            check_unit("force_unit", self.force_unit, "force")
        if self.angle_unit is not None:
            check_unit("angle_unit", self.angle_unit, "angle")
        object.__setattr__(self, "columns", _checked_columns(self.columns))
        if self.name_pattern is not None:
            NamePattern.parse(self.name_pattern)

    @property
    def pattern(self) -> NamePattern | None:
        """The parsed ``name_pattern``, if any."""
        return None if self.name_pattern is None else NamePattern.parse(self.name_pattern)


def _check_choice(key: str, value: object, allowed: Iterable[str]) -> None:
    allowed = tuple(allowed)
    if value is not None and value not in allowed:
        shown = ", ".join(repr(a) for a in allowed)
        raise InputDataError(f"{key} must be one of {shown}, got {value!r}")


def _check_encoding(encoding: object) -> None:
    try:
        codecs.lookup(encoding)  # type: ignore[arg-type]
    except (LookupError, TypeError):
        raise InputDataError(
            f'encoding must be a text encoding such as "utf-8" or "cp1252", got {encoding!r}'
        ) from None


def _checked_columns(columns: object) -> dict[str, str]:
    if not isinstance(columns, Mapping):
        raise InputDataError(
            'columns must be a table such as { angle_deg = "Angle [deg]", force_n = "Force [N]" }'
            f", got {columns!r}"
        )
    for name, header in columns.items():
        if not _FIELD_NAME.fullmatch(name):
            raise InputDataError(
                f"columns: {name!r} is not a column name of the product; use "
                f"{', '.join(COLUMN_NAMES)} or a lower-case covariate name such as temperature_c"
            )
        if not isinstance(header, str) or not header:
            raise InputDataError(f"columns.{name} must be the file's column header, got {header!r}")
    if len(set(columns.values())) != len(columns):
        raise InputDataError(f"columns gives one header to two names: {dict(columns)!r}")
    return dict(columns)


def detect_delimiter(lines: list[str], where: str) -> str:
    """The delimiter of a file's ``lines`` (the module's rule), or an InputDataError
    saying to set ``delimiter``."""
    rows = {d: _records(lines, d) for d in DELIMITERS}
    even = [d for d, found in rows.items() if _splits_evenly(found)]
    if not even:
        raise InputDataError(
            f"{where}: cannot tell its delimiter: none of comma, semicolon, tab splits the "
            f"header and every line into the same number of columns{_first_ragged(rows)} (a "
            "file cannot use ',' both between columns and as decimal mark); set [measurements] "
            'delimiter (and decimal), e.g. delimiter = ";"'
        )
    if len(even) == 1:
        return even[0]
    scores = {d: _numeric_fields([r for _, r in rows[d][1:]], d) for d in even}
    best = [d for d in even if scores[d] == max(scores.values())]
    if len(best) > 1:
        names = " and ".join(DELIMITERS[d] for d in best)
        raise InputDataError(
            f"{where}: cannot tell its delimiter: {names} both split every line into "
            f"{len(rows[best[0]][0][1])} columns; set [measurements] delimiter, e.g. "
            f"delimiter = {best[0]!r}"
        )
    return best[0]


def check_delimiter(lines: list[str], delimiter: str, where: str) -> str:
    """A stated ``delimiter``, if it splits the header and every line into the same number
    (≥ 2) of fields; else an InputDataError saying where it does not."""
    rows = {delimiter: _records(lines, delimiter)}
    if not _splits_evenly(rows[delimiter]):
        raise InputDataError(
            f"{where}: [measurements] delimiter = {delimiter!r} does not split it into columns"
            f"{_first_ragged(rows)}; check the key (or leave it out: it is detected)"
        )
    return delimiter


def _records(lines: list[str], delimiter: str) -> list[tuple[int, list[str]]]:
    """(line number, fields) of each non-empty line."""
    return [(n, r) for n, r in enumerate(csv.reader(lines, delimiter=delimiter), 1) if r]


def _splits_evenly(records: list[tuple[int, list[str]]]) -> bool:
    return bool(records) and len(records[0][1]) > 1 and len({len(r) for _, r in records}) == 1


def _first_ragged(rows: dict[str, list[tuple[int, list[str]]]]) -> str:
    """Where the delimiter that splits the header most stops fitting (for the error)."""
    delimiter = max(rows, key=lambda d: len(rows[d][0][1]) if rows[d] else 0)
    found = rows[delimiter]
    if not found:
        return ""
    if len(found[0][1]) < 2:
        return f" (split at each {DELIMITERS[delimiter]}, the header is one column)"
    width = len(found[0][1])
    line, fields = next(((n, r) for n, r in found if len(r) != width), found[0])
    return (
        f" (split at each {DELIMITERS[delimiter]}, the header has {width} columns, "
        f"line {line} has {len(fields)})"
    )


def _numeric_fields(rows: list[list[str]], delimiter: str) -> float:
    """The fraction of fields that are numbers (with either decimal mark, but not a comma
    in a comma-delimited file)."""
    marks = (".",) if delimiter == "," else DECIMALS
    values = [value.strip() for row in rows for value in row]
    numeric = sum(
        1
        for value in values
        if _WHOLE.fullmatch(value) or any(_NUMBER[mark].fullmatch(value) for mark in marks)
    )
    return numeric / max(len(values), 1)


def detect_decimal(values: Iterable[str], delimiter: str, where: str) -> str:
    """The decimal mark of a file's numeric fields ``values`` (the module's rule), or an
    InputDataError saying to set ``decimal``."""
    if delimiter == ",":
        return "."
    seen: dict[str, str] = {}
    for value in values:
        for mark in DECIMALS:
            if mark not in seen and _NUMBER[mark].fullmatch(value.strip()):
                seen[mark] = value
        if len(seen) == 2:
            raise InputDataError(
                f"{where}: cannot tell its decimal mark: it holds both {seen['.']!r} and "
                f"{seen[',']!r}; set [measurements] decimal, or export with one mark"
            )
    return "," if "," in seen else "."
