"""LS-DYNA as an external full solver: the user's keyword deck, our coating values.

LS-DYNA is not installed here: the deck writer and the output parsers are
tested on files in the documented formats, and the run path with a stand-in
executable (see ``tests/solvers``). What is relied on:

- ``*PARAMETER`` cards: eight 10-character fields, pairs of ``PRMRn`` (a type
  letter ``R``/``I``/``C``, then the name of ≤ 9 characters) and ``VALn``; the
  deck refers to a parameter as ``&NAME``.
- ``*MAT_SEATBELT_2D``: the coating fields of its card 3 are P1DOFF, FORM,
  ECOAT, TCOAT, SCOAT (10 characters each) — TCOAT before SCOAT, unlike
  ``*MAT_FABRIC``. The card number is a setting (``seatbelt_card``, default 3),
  so a deck of another keyword-manual revision can point elsewhere.
- ``rcforc`` (ASCII, ``*DATABASE_RCFORC``): after the ``{END LEGEND}`` block,
  one line per interface side and output time:
  ``master  <id> time <t> x <fx> y <fy> z <fz> mag <|f|> …`` (keyword–value
  pairs; newer versions append moments and areas), forces in global axes.
- ``nodout`` (ASCII, ``*DATABASE_NODOUT``): blocks headed
  ``n o d a l   p r i n t   o u t   f o r   t i m e  s t e p … ( at time T )``;
  the rotation block's columns are node, x-rot, y-rot, z-rot [rad], ….
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .._errors import InputDataError, SolverError
from ..effects import ModelState
from ._base import (
    Solver,
    beyond_the_coat,
    check_common_settings,
    command_list,
    curve_result,
    failed_result,
    guarded,
    register_solver,
    run_command,
    work_directory,
)
from ._state import model_state

__all__ = [
    "LSDYNA_UNITS",
    "LsDynaSolver",
    "RcforcHistory",
    "coating_parameters",
    "fill_parameters",
    "fill_seatbelt_card",
    "parse_nodout_rotation",
    "parse_rcforc",
]

FIELD = 10
COMMAND_ENV = "SURROGATE_LSDYNA_COMMAND"
DECK = "main.k"
LSDYNA_UNITS = {
    # name: (stress unit in MPa, length unit in mm, force unit in N)
    "mm-N-s": (1.0, 1.0, 1.0),  # MPa, N
    "mm-kg-ms": (1000.0, 1.0, 1000.0),  # GPa, kN
    "m-kg-s": (1e-6, 1000.0, 1.0),  # Pa, m, N
}


# -- the deck ---------------------------------------------------------------------------------
def coating_parameters(state: ModelState, *, units: str = "mm-N-s") -> dict[str, float]:
    """``ECOAT``, ``SCOAT``, ``TCOAT`` (and ``HCOAT``, the hardening tangent
    modulus, when the hardening effect is on) in the deck's units."""
    stress, length, _ = LSDYNA_UNITS[units]
    values = {
        "ECOAT": state.ecoat_mpa / stress,
        "SCOAT": state.scoat_mpa / stress,
        "TCOAT": state.tcoat_mm / length,
    }
    if state.hardening_ratio > 0.0:
        values["HCOAT"] = state.ecoat_mpa * state.hardening_ratio / stress
    return values


def format_real(value: float, width: int = FIELD, *, max_digits: int = 7) -> str:
    """A real number right-aligned in ``width`` characters: ``max_digits`` significant
    digits, fewer where they do not fit."""
    for digits in range(min(max_digits, width - 1), 0, -1):
        for text in (f"{value:.{digits}g}", f"{value:.{digits}E}"):
            if len(text) <= width and _same(text, value, digits):
                return text.rjust(width)
    raise InputDataError(f"{value!r} does not fit a {width}-character LS-DYNA field")


def _same(text: str, value: float, digits: int) -> bool:
    return math.isclose(float(text), value, rel_tol=10.0 ** (1 - digits), abs_tol=0.0)


def _parameter_card(pairs: Sequence[tuple[str, float]]) -> str:
    return "".join(f"R {name:<8}"[:FIELD] + format_real(value) for name, value in pairs)


def fill_parameters(template: str, values: Mapping[str, float]) -> str:
    """Set real ``*PARAMETER`` values in a keyword deck.

    Names already defined in a ``*PARAMETER`` card of the template get the new
    value in place (the field keeps its position); the rest are added in a new
    ``*PARAMETER`` block right after ``*KEYWORD``.

    Parameters
    ----------
    template : str
        The deck text.
    values : mapping
        Parameter name (≤ 9 characters, e.g. ``ECOAT``) → value in deck units.
    """
    for name in values:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,8}", name):
            raise InputDataError(f"LS-DYNA parameter names have 1–9 characters, got {name!r}")
    lines = template.splitlines()
    todo = {name.upper(): float(value) for name, value in values.items()}
    in_block = False
    for index, line in enumerate(lines):
        if line.startswith("*"):
            in_block = line.strip().upper() == "*PARAMETER"
            continue
        if in_block and not line.startswith("$"):
            lines[index] = _set_in_card(line, todo)
    if todo:
        at = next((i for i, line in enumerate(lines) if line.strip().upper() == "*KEYWORD"), None)
        if at is None:
            raise InputDataError("the LS-DYNA template has no *KEYWORD line; is it a keyword deck?")
        pairs = list(todo.items())
        block = ["*PARAMETER", "$ coating values written by surrogate"]
        block += [_parameter_card(pairs[i : i + 4]) for i in range(0, len(pairs), 4)]
        lines[at + 1 : at + 1] = block
    return "\n".join(lines) + "\n"


def _set_in_card(line: str, todo: dict[str, float]) -> str:
    padded = line.ljust(8 * FIELD)
    for k in range(0, 8 * FIELD, 2 * FIELD):
        field = padded[k : k + FIELD]
        kind, name = field[:1].upper(), field[1:].strip().upper()
        if name in todo and kind in ("R", "I"):
            value = todo.pop(name)
            field = f"R {name:<8}"[:FIELD]
            padded = padded[:k] + field + format_real(value) + padded[k + 2 * FIELD :]
    return padded.rstrip()


# (field index on card 3, our name) — P1DOFF and FORM (fields 0 and 1) are left as they are
_SEATBELT_FIELDS = ((2, "ECOAT"), (3, "TCOAT"), (4, "SCOAT"))


def fill_seatbelt_card(template: str, values: Mapping[str, float], *, card: int = 3) -> str:
    """Write ECOAT, TCOAT, SCOAT into the coating fields of every ``*MAT_SEATBELT_2D``.

    The fields are 3, 4 and 5 (10 characters each) of data card ``card``
    (comment lines ``$`` and a ``_TITLE`` line are not cards).
    """
    lines = template.splitlines()
    found = 0
    index = 0
    while index < len(lines):
        keyword = lines[index].strip().upper()
        index += 1
        if not keyword.startswith("*MAT_SEATBELT_2D"):
            continue
        cards = [i for i in range(index, len(lines)) if not lines[i].startswith("$")]
        skip = 1 if keyword.endswith("_TITLE") else 0
        if len(cards) < skip + card or lines[cards[skip + card - 1]].startswith("*"):
            raise InputDataError(f"{keyword} in the LS-DYNA template has no card {card}")
        target = cards[skip + card - 1]
        padded = lines[target].ljust(8 * FIELD)
        for field, name in _SEATBELT_FIELDS:
            start = field * FIELD
            padded = padded[:start] + format_real(values[name]) + padded[start + FIELD :]
        lines[target] = padded.rstrip()
        found += 1
    if not found:
        raise InputDataError(
            'the LS-DYNA template has no *MAT_SEATBELT_2D card; use fill = "parameter"'
        )
    return "\n".join(lines) + "\n"


# -- the output -------------------------------------------------------------------------------
@dataclass(frozen=True)
class RcforcHistory:
    """One interface side from ``rcforc``: times and the resultant force (n, 3)."""

    time: np.ndarray
    force: np.ndarray


def parse_rcforc(text: str, *, interface: int = 1, side: str = "master") -> RcforcHistory:
    """The resultant contact force of one interface side over time.

    Parameters
    ----------
    text : str
        The ``rcforc`` file.
    interface : int
        Contact interface number (the order of ``*CONTACT`` in the deck, or its ID).
    side : {"master", "slave"}
        Which side's resultant to read (they are equal and opposite).
    """
    times: list[float] = []
    forces: list[list[float]] = []
    for line in text.splitlines():
        tokens = line.split()
        if len(tokens) < 10 or tokens[0].lower() != side or tokens[2].lower() != "time":
            continue
        try:
            if int(tokens[1]) != interface:
                continue
            pairs = dict(zip(tokens[2::2], tokens[3::2], strict=False))
            times.append(float(pairs["time"]))
            forces.append([float(pairs[axis]) for axis in ("x", "y", "z")])
        except (ValueError, KeyError):
            raise SolverError(f"rcforc: cannot read the line {line.strip()!r}") from None
    if not times:
        raise SolverError(f"rcforc has no {side} lines of interface {interface}")
    return RcforcHistory(np.array(times), np.array(forces))


_NODOUT_TIME = re.compile(r"n o d a l\s+p r i n t\s+o u t.*\(\s*at time\s+(\S+)\s*\)")


def parse_nodout_rotation(text: str, node: int, *, axis: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Times and the rotation [rad] about ``axis`` (1 = x, 2 = y, 3 = z) of ``node``.

    Only the rotation blocks (header ``x-rot``) are read.
    """
    times: list[float] = []
    angles: list[float] = []
    time = None
    rotation_block = False
    for line in text.splitlines():
        match = _NODOUT_TIME.search(line)
        if match:
            time, rotation_block = float(match.group(1)), False
            continue
        if "nodal point" in line:
            rotation_block = "x-rot" in line
            continue
        tokens = line.split()
        if rotation_block and time is not None and tokens and tokens[0] == str(node):
            times.append(time)
            angles.append(float(tokens[axis]))
    if not times:
        raise SolverError(f"nodout has no rotation of node {node}")
    return np.array(times), np.array(angles)


def termination_time(deck: str) -> float:
    """ENDTIM, the first field of ``*CONTROL_TERMINATION`` (where ``&NAME`` is not used)."""
    lines = deck.splitlines()
    for index, line in enumerate(lines):
        if line.strip().upper().startswith("*CONTROL_TERMINATION"):
            for card in lines[index + 1 :]:
                if not card.startswith("$"):
                    try:
                        return float(card[:FIELD])
                    except ValueError:
                        break
    raise InputDataError(
        "the LS-DYNA template needs *CONTROL_TERMINATION with a numeric ENDTIM, "
        "or set rotation_node to read the rotation from nodout"
    )


# -- the solver -------------------------------------------------------------------------------
@register_solver
class LsDynaSolver(Solver):
    """The user's LS-DYNA bending model with the coating of each run.

    Settings: ``template`` (keyword deck, required), ``command`` (argument list
    or a string split like a shell would, never run by one; default from the
    environment variable ``SURROGATE_LSDYNA_COMMAND``, else ``lsdyna``; the
    deck name is appended as ``i=main.k``), ``fill`` (``parameter`` or
    ``seatbelt_card``), ``seatbelt_card`` (3), ``units`` (``mm-N-s``,
    ``mm-kg-ms``, ``m-kg-s``), ``contact`` (rcforc interface, 1),
    ``rotation_node`` (read the rotation from ``nodout``; otherwise the imposed
    rotation is a linear ramp 0 → max angle over ENDTIM), ``timeout_s``,
    ``keep_workdir``, ``workdir_root``.
    """

    name: ClassVar[str] = "lsdyna"
    version: ClassVar[str] = "lsdyna-adapter-1"
    settings_keys: ClassVar[tuple[str, ...]] = (
        "template",
        "command",
        "fill",
        "seatbelt_card",
        "units",
        "contact",
        "rotation_node",
        "timeout_s",
        "keep_workdir",
        "workdir_root",
        "template_sha256",
    )
    # the template's content is in template_sha256; its path says only where it is
    run_settings: ClassVar[tuple[str, ...]] = (*Solver.run_settings, "template")

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        """Validated settings, with ``template_sha256`` (the template's content) added,
        so an edited template never reuses a cached run; a template that changed
        since its hash was taken is an error."""
        checked = super().check_settings(settings)
        check_common_settings(checked)
        template = checked.get("template")
        if not isinstance(template, str) or not template:
            raise InputDataError("[solver] template (the LS-DYNA keyword deck) is required")
        try:
            digest = hashlib.sha256(Path(template).read_bytes()).hexdigest()[:24]
        except OSError as error:
            raise InputDataError(f"[solver] template {template}: {error.strerror}") from None
        if checked.setdefault("template_sha256", digest) != digest:
            raise InputDataError(
                f"[solver] template {template} changed since the study was loaded; "
                "load the study again"
            )
        if checked.get("fill", "parameter") not in ("parameter", "seatbelt_card"):
            raise InputDataError(
                f"[solver] fill must be parameter or seatbelt_card, got {checked['fill']!r}"
            )
        if checked.get("units", "mm-N-s") not in LSDYNA_UNITS:
            raise InputDataError(
                f"[solver] units must be one of {', '.join(LSDYNA_UNITS)}, got {checked['units']!r}"
            )
        return checked

    def solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        return guarded(lambda: self._solve(inputs))

    def refuses(self, state: ModelState) -> str | None:
        """The deck gets the coat (and its hardening) only: an effect beyond it would be
        left out silently, so it is refused."""
        effect = beyond_the_coat(state)
        if effect is None:
            return None
        return (
            f"the lsdyna adapter passes only the coat to your deck, not {effect}; model it "
            "in the template and leave it out of the model's effects"
        )

    def _solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        settings = self.check_settings(inputs.get("solver_settings") or {})
        state = model_state(inputs)
        refused = self.refuses(state)
        if refused is not None:
            return failed_result(refused)
        deck = self.deck(state, settings)
        with work_directory(settings, prefix="lsdyna-") as workdir:
            (workdir / DECK).write_text(deck, encoding="utf-8")
            done = run_command(
                [*_command(settings), f"i={DECK}"],
                cwd=workdir,
                timeout_s=float(settings.get("timeout_s", 3600.0)),
            )
            rcforc = _read(workdir / "rcforc")
            nodout = _read(workdir / "nodout") if "rotation_node" in settings else ""
            messages = "\n".join((_read(workdir / "d3hsp"), done.stdout, done.stderr))
        if done.returncode != 0 or "E r r o r   t e r m i n a t i o n" in messages:
            return failed_result(f"LS-DYNA failed (exit {done.returncode}): {_reason(messages)}")
        return self._curve(state, settings, deck, rcforc, nodout)

    @staticmethod
    def deck(state: ModelState, settings: Mapping[str, Any]) -> str:
        """The user's template with this run's coating values filled in."""
        path = Path(str(settings["template"]))
        try:
            template = path.read_text(encoding="utf-8")
        except OSError as error:
            raise InputDataError(f"[solver] template {path}: {error.strerror}") from None
        values = coating_parameters(state, units=settings.get("units", "mm-N-s"))
        if settings.get("fill", "parameter") == "seatbelt_card":
            return fill_seatbelt_card(template, values, card=int(settings.get("seatbelt_card", 3)))
        return fill_parameters(template, values)

    @staticmethod
    def _curve(
        state: ModelState, settings: Mapping[str, Any], deck: str, rcforc: str, nodout: str
    ) -> dict[str, Any]:
        history = parse_rcforc(rcforc, interface=int(settings.get("contact", 1)))
        span = state.rig.max_angle_deg
        if "rotation_node" in settings:
            times, radians = parse_nodout_rotation(nodout, int(settings["rotation_node"]))
            angle = np.interp(history.time, times, np.abs(np.degrees(radians)))
        else:
            angle = span * history.time / termination_time(deck)
        _, _, force_unit = LSDYNA_UNITS[settings.get("units", "mm-N-s")]
        force = history.force * force_unit
        keep = np.concatenate(([True], np.diff(angle) > 0))  # drop repeated output times
        return curve_result(
            angle[keep],
            np.linalg.norm(force, axis=1)[keep],
            np.abs(force[:, 2])[keep],
            span,
        )


def _command(settings: Mapping[str, Any]) -> list[str]:
    return command_list(settings.get("command") or os.environ.get(COMMAND_ENV) or "lsdyna")


def _read(path: Path) -> str:
    return path.read_text(encoding="utf-8", errors="replace") if path.exists() else ""


def _reason(messages: str) -> str:
    for line in messages.splitlines():
        if "*** Error" in line or "E r r o r" in line:
            return line.strip()
    tail = [line.strip() for line in messages.splitlines() if line.strip()]
    return tail[-1] if tail else "no message"
