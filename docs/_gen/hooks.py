"""MkDocs hooks: the reference pages are generated from the code at build time.

A page asks for a generated part with an HTML comment on a line of its own::

    <!-- generated: cli -->           every command and option (the argparse parsers)
    <!-- generated: study-keys -->    every study-file key (surrogate.study._keys, Rig)
    <!-- generated: json -->          every ``--json`` output's keys (the result records)
    <!-- generated: exit-codes -->    the exit codes (surrogate._cli's constants)
    <!-- generated: effects -->       the built-in effects (the effect registry)
    <!-- include: studies/paper_coating.toml -->   a file of the repository, verbatim

Nothing of these is pasted into a page, so a page cannot be out of date: a changed option,
key or field changes the page at the next build (tests/docs/test_docs.py builds it with
``--strict`` and checks that every option, key and field is on it). A command whose
``--json`` has no record in :data:`JSON_RECORDS` is a build warning, so an error under
``--strict``.

"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
import inspect
import json
import logging
import re
import textwrap
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
log = logging.getLogger("mkdocs.plugins.surrogate_reference")

#: command → the record whose fields are its ``--json`` keys (``module:Class``)
JSON_RECORDS = {
    "simulate": "surrogate.solvers._simulate:BendingCurve",
    "doe": "surrogate.identify._commands:DoeResult",
    "fit": "surrogate.identify._commands:FitResult",
    "predict": "surrogate.identify._commands:PredictResult",
    "run": "surrogate.identify._loop:RunResult",
    "calibrate": "surrogate.calibration._calibrate:CalibrationResult",
    "compare": "surrogate.calibration._compare:CompareResult",
    "diagnose": "surrogate.calibration._diagnose:DiagnosisResult",
    "export": "surrogate.identify._export:ExportResult",
    "report": "surrogate.reporting._report:ReportResult",
    "worker": "surrogate.identify._worker:WorkerResult",
    "status": "surrogate.identify._status:StatusResult",
    "next-test": "surrogate.design._next_test:NextTestResult",
}

_MARKER = re.compile(r"^<!-- (generated|include): ([\w./-]+) -->$", re.MULTILINE)


# -- MkDocs events -----------------------------------------------------------------------------
def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    return expand(markdown)


# -- the generated parts -----------------------------------------------------------------------
def expand(markdown: str) -> str:
    """``markdown`` with every generated part and include filled in."""

    def replace(match: re.Match[str]) -> str:
        kind, name = match.groups()
        if kind == "include":
            path = ROOT / name
            language = {".toml": "toml", ".py": "python"}.get(path.suffix, "text")
            return f"```{language}\n{path.read_text(encoding='utf-8').rstrip()}\n```"
        return GENERATORS[name]()

    return _MARKER.sub(replace, markdown)


def cli_reference() -> str:
    """Every command of ``surrogate`` with its usage and a table of its arguments."""
    from surrogate._cli import _build_parser

    parser = _build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {action.dest: action.help for action in subparsers._choices_actions}
    parts = [
        "## `surrogate`\n",
        f"{parser.description}\n",
        _usage(parser),
        _arguments_table(parser, skip_subcommands=True),
    ]
    for name, command in subparsers.choices.items():
        parts += [
            f"## `surrogate {name}`\n",
            f"{_sentence(helps.get(name) or '')}\n",
            _usage(command),
            _arguments_table(command),
        ]
        if name in JSON_RECORDS:
            parts.append(f"`--json` keys: [`{name}`](json.md#{name}).\n")
    return "\n".join(part for part in parts if part)


def _usage(parser: argparse.ArgumentParser) -> str:
    usage = parser.format_usage().strip().removeprefix("usage: ")
    return f"```text\n{usage}\n```\n"


def _arguments_table(parser: argparse.ArgumentParser, skip_subcommands: bool = False) -> str:
    rows = []
    formatter = parser._get_formatter()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and skip_subcommands:
            continue
        if action.help == argparse.SUPPRESS:
            continue
        if action.option_strings:
            metavar = (
                ""
                if action.nargs == 0
                else f" {formatter._format_args(action, action.dest.upper())}"
            )
            name = ", ".join(f"`{option}{metavar}`" for option in action.option_strings)
        else:
            name = f"`{formatter._format_args(action, action.dest)}`"
        meaning = formatter._expand_help(action) if action.help else ""
        if action.choices and not isinstance(action, argparse._SubParsersAction):
            meaning += " (one of " + ", ".join(f"`{c}`" for c in action.choices) + ")"
        if getattr(action, "required", False) and action.option_strings:
            meaning += " (required)"
        rows.append(f"| {name} | {_default(action)} | {_cell(meaning)} |")
    if not rows:
        return ""
    return "| argument | default | meaning |\n|---|---|---|\n" + "\n".join(rows) + "\n"


def _default(action: argparse.Action) -> str:
    default = action.default
    if default in (None, False, [], argparse.SUPPRESS) or not action.option_strings:
        return ""
    return f"`{default}`"


def study_keys_reference() -> str:
    """Every section and key of a study file, with type, default and meaning."""
    from surrogate.solvers import available_solvers, get_solver
    from surrogate.study._keys import KEYS, SECTIONS, SOLVER_SETTINGS, rig_keys

    parts = []
    for section in SECTIONS:
        rows = rig_keys() if section == "rig" else tuple(k for k in KEYS if k.section == section)
        parts.append(f"## `[{section}]`\n")
        parts.append(_keys_table(rows))
        if section == "parameters":
            parts.append("Each parameter's table takes:\n")
            parts.append(_keys_table(tuple(k for k in KEYS if k.section == "parameters.*")))
        if section == "solver":
            for kind in available_solvers():
                solver = get_solver(kind)
                parts.append(f'### `kind = "{kind}"`\n')
                if not solver.settings_keys:
                    parts.append("No further settings.\n")
                    continue
                rows_text = []
                for key in solver.settings_keys:
                    if key not in SOLVER_SETTINGS:
                        log.warning(
                            "solver setting %s.%s has no meaning in SOLVER_SETTINGS", kind, key
                        )
                    identity = "no" if key in solver.run_settings else "yes"
                    rows_text.append(
                        f"| `{key}` | {identity} | {_cell(SOLVER_SETTINGS.get(key, ''))} |"
                    )
                parts.append(
                    "| key | names the run (result cache) | meaning |\n|---|---|---|\n"
                    + "\n".join(rows_text)
                    + "\n"
                )
    return "\n".join(parts)


def _keys_table(rows: tuple[Any, ...]) -> str:
    lines = ["| key | type | default | meaning |", "|---|---|---|---|"]
    for key in rows:
        lines.append(
            f"| `{key.name}` | {key.type} | {_toml(key.default)} | {_cell(_rst(key.meaning))} |"
        )
    return "\n".join(lines) + "\n"


def _toml(value: Any) -> str:
    from surrogate.study._keys import REQUIRED

    if value is None:
        return "not set"
    if value == REQUIRED:
        return "**required**"
    if isinstance(value, str) and " " in value:
        return value
    return f"`{json.dumps(value)}`"


def json_reference() -> str:
    """Every command's ``--json`` keys: the fields of its result record and its docstring."""
    parts = []
    for command, where in JSON_RECORDS.items():
        record = _record(where)
        keys = _json_keys(record)
        doc = inspect.getdoc(record) or ""
        described = _described(doc)
        parts.append(f"## `{command}`\n")
        parts.append(
            f"`surrogate {command} --json` prints one object, the fields of "
            f"[`{record.__name__}`](api.md#{record.__module__}.{record.__name__}).\n"
        )
        lines = ["| key | type | meaning |", "|---|---|---|"]
        hints = {f.name: f.type for f in dataclasses.fields(record)}
        for key in keys:
            type_text = str(hints.get(key, "list[float]")).replace("|", "or")
            type_text = type_text.replace("np.ndarray", "list[float]")
            meaning = described.get(key, "").rstrip(";,") + ("." if key in described else "")
            lines.append(f"| `{key}` | `{type_text}` | {_cell(_rst(meaning.replace('..', '.')))} |")
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)


def _record(where: str) -> type:
    module, name = where.split(":")
    return getattr(importlib.import_module(module), name)


def _json_keys(record: type) -> list[str]:
    """The record's ``to_json`` keys: its fields where it returns ``asdict(self)``, else the
    keys of the dict literal it returns."""
    source = textwrap.dedent(inspect.getsource(record.to_json))
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Return) and isinstance(node.value, ast.Dict):
            return [k.value for k in node.value.keys if isinstance(k, ast.Constant)]
    return [f.name for f in dataclasses.fields(record)]


def _described(doc: str) -> dict[str, str]:
    """Per key, what the docstring says of it: its numpydoc ``Attributes`` entry, else the
    first sentence that names it in double back-quotes."""
    described: dict[str, str] = {}
    attributes = re.search(r"Attributes\n-+\n(.*?)(\n\n\S|\Z)", doc, re.DOTALL)
    if attributes:
        for entry in re.finditer(r"^(\S[^\n]*)\n((?:    [^\n]*\n?)+)", attributes.group(1), re.M):
            names = [n.strip() for n in entry.group(1).split(":")[0].split(",")]
            text = " ".join(line.strip() for line in entry.group(2).splitlines())
            for name in names:
                described[name] = text
    sentences = re.split(r"(?<=[.;])\s+(?=[`A-Z(])", " ".join(doc.split()))
    subjects: dict[str, str] = {}
    for sentence in sentences:
        names = re.findall(r"``(\w+)``", sentence)
        if names:  # the sentence is about the first key it names
            subjects.setdefault(names[0], sentence)
        for name in names:
            described.setdefault(name, sentence)
    return {**described, **{k: v for k, v in subjects.items() if k not in _attributes(doc)}}


def _attributes(doc: str) -> set[str]:
    found = re.search(r"Attributes\n-+\n(.*?)(\n\n\S|\Z)", doc, re.DOTALL)
    if not found:
        return set()
    names = re.findall(r"^(\S[^\n:]*)", found.group(1), re.M)
    return {n.strip() for line in names for n in line.split(",")}


def exit_codes_reference() -> str:
    """The exit codes, from the constants of :mod:`surrogate._cli`."""
    import signal

    from surrogate import _cli

    rows = [
        (
            "0",
            "the command did what it was asked (a calibration that did not converge is "
            "still 0: its `status` says so)",
        ),
        (
            str(_cli.EXIT_USAGE),
            "bad input: an option, a value out of range, NaN, a malformed "
            "CSV or study file, an unusable storage; one line on stderr, "
            "nothing written",
        ),
        (
            str(_cli.EXIT_SOLVER),
            "a full-solver run failed (the line names the angle or the "
            "solver's reason); `run --jobs N`: runs still open after four "
            "rounds of local worker processes",
        ),
        (str(128 + int(signal.SIGINT)), "interrupted by Ctrl-C (SIGINT)"),
        (
            str(128 + int(signal.SIGTERM)),
            "stopped by SIGTERM (what schedulers send); the "
            "finished runs are kept, the same command resumes",
        ),
    ]
    return (
        "| exit code | meaning |\n|---|---|\n"
        + "\n".join(f"| `{code}` | {text} |" for code, text in rows)
        + "\n"
    )


def effects_reference() -> str:
    """The built-in effects: name, parameters (bounds, off value, unit), conditions read."""
    from surrogate.effects import available_effects, get_effect

    lines = [
        "| effect | parameters (low – high, off, unit) | reads | what it does |",
        "|---|---|---|---|",
    ]
    for name in available_effects():
        effect = get_effect(name)
        params = "<br>".join(
            f"`{p.name}` {p.low:g} – {p.high:g}, off {p.off:g}" + (f" [{p.unit}]" if p.unit else "")
            for p in effect.parameters
        )
        reads = ", ".join(f"`{r}`" for r in effect.reads) or "—"
        lines.append(f"| `{name}` | {params} | {reads} | {_cell(effect.description)} |")
    return "\n".join(lines) + "\n"


GENERATORS = {
    "cli": cli_reference,
    "study-keys": study_keys_reference,
    "json": json_reference,
    "exit-codes": exit_codes_reference,
    "effects": effects_reference,
}


# -- text helpers ------------------------------------------------------------------------------
def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def _rst(text: str) -> str:
    """reST inline markup of docstrings → Markdown (``x`` → `x`, :class:`~a.B` → `B`)."""
    text = re.sub(r":\w+:`~?([^`]+)`", lambda m: f"`{m.group(1).split('.')[-1]}`", text)
    return text.replace("``", "`")


def _sentence(text: str) -> str:
    text = text.strip()
    return (text[:1].upper() + text[1:]).rstrip(".") + "." if text else ""
