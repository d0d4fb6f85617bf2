"""Security rules that a reading of the source can check.

No pickle/joblib (nor ``allow_pickle``) anywhere in the package: surrogates,
samples and results are JSON/CSV. No shell. The dashboard binds 127.0.0.1 only
(the serving test checks the socket). Nothing is attached to the dashboard as
HTML or SVG: figures go as plotly JSON, the report as a markdown note.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "surrogate"
SOURCES = sorted(PACKAGE.rglob("*.py"))
UNSAFE_MODULES = {"pickle", "cPickle", "joblib", "dill", "cloudpickle", "shelve", "marshal"}


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_unpickling_and_no_shell(path):
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            assert not {a.name.split(".")[0] for a in node.names} & UNSAFE_MODULES
        elif isinstance(node, ast.ImportFrom):
            assert (node.module or "").split(".")[0] not in UNSAFE_MODULES
        elif isinstance(node, ast.Attribute):
            assert node.attr not in {"read_pickle", "to_pickle"}, f"{path}:{node.lineno}"
        elif isinstance(node, ast.keyword) and node.arg in {"allow_pickle", "shell"}:
            assert isinstance(node.value, ast.Constant) and node.value.value is False


def test_dashboard_binds_loopback_only():
    from surrogate.storage._serve import HOST

    assert HOST == "127.0.0.1"


def test_no_html_or_svg_artifacts():
    for path in SOURCES:
        text = path.read_text(encoding="utf-8")
        assert "upload_artifact" not in text or not any(
            kind in text for kind in (".html", ".svg", "text/html", "image/svg")
        ), path
