"""The package as users install it: ``pip install .`` (not editable) gives a working CLI,
and ``surrogate --version`` says which version it is."""

from __future__ import annotations

import shutil
import site
import subprocess
import sys
import tomllib
from importlib.metadata import PackageNotFoundError
from pathlib import Path

import pytest

import surrogate
from tests.conftest import REPO


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))


def test_version_prints_the_package_version_and_exits_0(in_process):
    code, out, err = in_process("--version")
    assert (code, err) == (0, "")
    assert out == f"surrogate {_pyproject()['project']['version']}\n"


def test_version_without_installed_metadata_is_the_modules(monkeypatch, in_process):
    def not_installed(name):
        raise PackageNotFoundError(name)

    monkeypatch.setattr("importlib.metadata.version", not_installed)
    assert in_process("--version")[:2] == (0, f"surrogate {surrogate.__version__}\n")


def test_the_modules_version_is_the_projects():
    """Two places hold the version (the fallback above needs it): they agree."""
    assert surrogate.__version__ == _pyproject()["project"]["version"]


def test_every_subpackage_is_found_by_the_package_find_rule():
    """``[tool.setuptools.packages.find]`` must list every folder of Python code (a folder
    without ``__init__.py`` would be left out of the wheel)."""
    include = _pyproject()["tool"]["setuptools"]["packages"]["find"]["include"]
    assert include == ["surrogate*"]
    for folder in (REPO / "surrogate").rglob("*"):
        if folder.is_dir() and folder.name != "__pycache__" and any(folder.glob("*.py")):
            assert (folder / "__init__.py").is_file(), folder


@pytest.mark.slow
def test_pip_install_dot_gives_a_working_cli(tmp_path):
    """A fresh venv, the project installed from a copy of its sources (not editable, so
    nothing of this checkout is imported), the dependencies those of the running
    interpreter through a ``.pth`` file, so nothing is downloaded; about 5 s.
    (``venv --system-site-packages`` would not do: run from a venv, it shows the base
    interpreter's packages, not the venv's.)"""
    source = tmp_path / "source"
    shutil.copytree(REPO / "surrogate", source / "surrogate", ignore=_built)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    venv = tmp_path / "venv"
    _run(sys.executable, "-m", "venv", "--without-pip", venv)
    python = venv / "bin" / "python"
    purelib = _run(python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))")
    Path(purelib.strip(), "running-interpreter.pth").write_text(
        "\n".join(site.getsitepackages()) + "\n", encoding="utf-8"
    )
    pip = (python, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index")
    _run(*pip, "--quiet", source, cwd=tmp_path)
    where = _run(python, "-c", "import surrogate; print(surrogate.__file__)", cwd=tmp_path)
    assert Path(where.strip()).is_relative_to(venv), where
    command = venv / "bin" / "surrogate"
    assert _run(command, "--version", cwd=tmp_path) == f"surrogate {surrogate.__version__}\n"
    assert "--ecoat" in _run(command, "simulate", "--help", cwd=tmp_path)
    installed = Path(where.strip()).parent
    assert (installed / "py.typed").is_file()
    assert _packages(installed) == _packages(REPO / "surrogate")


def _built(folder: str, names: list[str]) -> set[str]:
    return {name for name in names if name == "__pycache__"}


def _packages(root: Path) -> set[str]:
    return {str(p.parent.relative_to(root)) for p in root.rglob("__init__.py")}


def _run(*args: object, cwd: Path | None = None) -> str:
    done = subprocess.run(
        [str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout
