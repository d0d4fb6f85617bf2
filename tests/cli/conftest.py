"""The CLI in this process: the refusals' tests run ``surrogate._cli.main`` (the same code
as the command, without a Python start-up of 1–4 s each); the runs a user makes keep
the real command in a subprocess."""

import pytest

from surrogate._cli import main


@pytest.fixture
def in_process(capsys, monkeypatch):
    """``in_process(*args, cwd=None)`` → (exit code, stdout, stderr) of ``surrogate ARGS``."""

    def call(*args, cwd=None):
        if cwd is not None:
            monkeypatch.chdir(cwd)
        capsys.readouterr()
        try:
            code = main([str(a) for a in args])
        except SystemExit as stop:
            code = stop.code
        out, err = capsys.readouterr()
        return code, out, err

    return call
