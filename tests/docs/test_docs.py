"""The manual builds with ``mkdocs build --strict`` and its reference pages are the code's.

The reference pages (CLI, study file, ``--json`` keys, exit codes) are generated at build
time by docs/_gen/hooks.py, so they cannot be out of date; these tests show it: every
option, key and field is on the built pages, and a change in the code changes the page.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import html
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.docs


def _needs_mkdocs() -> None:
    """Skip without mkdocs on a developer's machine; in CI (CI=true) it must be there."""
    if importlib.util.find_spec("mkdocs") is None and os.environ.get("CI") != "true":
        pytest.skip("mkdocs is not installed (pip install -e '.[docs]'; scripts/setup.sh does)")


def _hooks() -> ModuleType:
    spec = importlib.util.spec_from_file_location("docs_hooks", REPO / "docs/_gen/hooks.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    _needs_mkdocs()
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        timeout=600,
    )
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stderr[-5000:]}"
    return out


def _page(site: Path, name: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", (site / name / "index.html").read_text()))


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    from surrogate._cli import _build_parser

    parser = _build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_the_manual_builds_strict(site: Path) -> None:
    for page in ("index.html", "tutorial/identify/index.html", "reference/api/index.html"):
        assert (site / page).exists(), page


def test_every_command_and_option_is_on_the_cli_page(site: Path) -> None:
    text = _page(site, "reference/cli")
    for name, parser in _subcommands().items():
        assert f"surrogate {name}" in text
        for action in parser._actions:
            for option in action.option_strings:
                assert option in text, f"{name} {option}"


def test_every_study_key_is_on_the_study_file_page(site: Path) -> None:
    from surrogate.solvers import available_solvers, get_solver
    from surrogate.study._keys import SECTIONS, keys

    text = _page(site, "reference/study-file")
    for section in SECTIONS:
        assert f"[{section}]" in text
        for key in keys(section):
            assert key in text, f"[{section}] {key}"
    for kind in available_solvers():
        for key in get_solver(kind).settings_keys:
            assert key in text, f"[solver] {key} ({kind})"


def test_every_json_key_is_on_the_json_page(site: Path) -> None:
    hooks = _hooks()
    text = _page(site, "reference/json")
    for command, where in hooks.JSON_RECORDS.items():
        for key in hooks._json_keys(hooks._record(where)):
            assert re.search(rf"\b{key}\b", text), f"{command}: {key}"


def test_every_command_with_json_output_has_its_record_on_the_json_page() -> None:
    hooks = _hooks()
    for name, parser in _subcommands().items():
        if any("--json" in action.option_strings for action in parser._actions):
            assert name in hooks.JSON_RECORDS, f"add `{name}` to JSON_RECORDS in docs/_gen/hooks.py"


def test_a_changed_parser_changes_the_cli_page(monkeypatch: pytest.MonkeyPatch) -> None:
    """By construction: the page is made from the parsers when the manual is built."""
    from surrogate import _cli

    build = _cli._build_parser

    def with_a_new_option() -> argparse.ArgumentParser:
        parser = build()
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        action.choices["run"].add_argument("--brand-new", help="an option added today")
        return parser

    hooks = _hooks()
    assert "--brand-new" not in hooks.cli_reference()
    monkeypatch.setattr(_cli, "_build_parser", with_a_new_option)
    assert "`--brand-new BRAND_NEW`" in hooks.cli_reference()
    assert "an option added today" in hooks.cli_reference()


def test_a_changed_key_table_changes_the_study_file_page(monkeypatch: pytest.MonkeyPatch) -> None:
    from surrogate.study import _keys

    extra = _keys.StudyKey("budget", "brand_new_runs", "integer", 7, "Runs added today.")
    monkeypatch.setattr(_keys, "KEYS", (*_keys.KEYS, extra))
    assert (
        "| `brand_new_runs` | integer | `7` | Runs added today. |"
        in _hooks().study_keys_reference()
    )


def test_the_loader_checks_keys_against_the_declared_table() -> None:
    """Every unknown-key check of surrogate/study/_spec.py reads surrogate.study._keys."""
    tree = ast.parse((REPO / "surrogate/study/_spec.py").read_text(encoding="utf-8"))
    calls = [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "_only"
    ]
    assert len(calls) >= 8
    assert re.search(
        r'^_SECTIONS = keys\(""\)', (REPO / "surrogate/study/_spec.py").read_text(), re.M
    )
    for call in calls:
        allowed = call.args[1]
        if isinstance(allowed, ast.Name) and allowed.id == "_SECTIONS":  # = keys("")
            continue
        assert isinstance(allowed, ast.Call) and getattr(allowed.func, "id", None) == "keys", (
            f"_spec.py line {call.lineno}: declare the keys in surrogate/study/_keys.py and "
            "pass keys(section)"
        )


def test_the_declared_defaults_are_the_loaders() -> None:
    from surrogate.study._cluster import ClusterSettings
    from surrogate.study._keys import KEYS, keys
    from surrogate.study._spec import Budget, Constraints, Targets, parse_study

    spec = parse_study({"study": {"name": "x"}, "targets": {"f60_n": 10.0}})
    records = {
        "budget": Budget(),
        "constraints": Constraints(),
        "targets": Targets(),
        "cluster": ClusterSettings(),
    }
    for key in KEYS:
        if key.section in records and key.name in {
            f.name for f in dataclasses.fields(records[key.section])
        }:
            value = getattr(records[key.section], key.name)
            assert (list(value) if isinstance(value, tuple) else value) == key.default, key
    assert set(keys("cluster")) == {f.name for f in dataclasses.fields(ClusterSettings)}
    declared = {(k.section, k.name): k.default for k in KEYS}
    assert spec.seed == declared["study", "seed"]
    assert spec.solver == declared["solver", "kind"]
    assert spec.multi_fidelity == declared["solver", "multi_fidelity"]
    assert list(spec.preference_order) == declared["preferences", "order"]
    assert list(spec.effects) == declared["model", "effects"]
    assert spec.targets.tolerance == declared["targets", "tolerance"]


def test_an_undeclared_key_is_refused_with_the_declared_list() -> None:
    from surrogate import InputDataError
    from surrogate.study._spec import parse_study

    with pytest.raises(InputDataError, match="allowed: initial_samples, max_solver_calls"):
        parse_study({"study": {"name": "x"}, "targets": {"f60_n": 1.0}, "budget": {"runs": 3}})


def test_every_solver_setting_has_a_meaning() -> None:
    from surrogate.solvers import available_solvers, get_solver
    from surrogate.study._keys import SOLVER_SETTINGS

    for kind in available_solvers():
        for key in get_solver(kind).settings_keys:
            assert key in SOLVER_SETTINGS, f"[solver] {key} of {kind}: add it to SOLVER_SETTINGS"
