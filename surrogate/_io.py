"""Writing files safely: all or nothing."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ._errors import InputDataError

__all__ = ["atomic_write_text", "check_output_file", "check_output_folder"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_output_file(path: str | os.PathLike[str]) -> Path:
    """``path`` as a file to write, or the one-line error every command gives: a folder
    named where a file is wanted, or a folder that does not exist (not created: a typo
    would otherwise make folders anywhere). Called before the work, not only at the
    write, so nothing is computed for an output that cannot be written."""
    target = Path(path)
    if target.is_dir():
        raise InputDataError(f"{target} is a folder; name the file to write")
    _check_writable_folder(target.parent)  # "." for a bare file name
    return target


def _check_writable_folder(folder: Path) -> None:
    """The one rule for where an output goes: a folder that exists and can be written."""
    if not folder.is_dir():
        state = (
            "is a file; choose another" if folder.exists() else "does not exist; create it first"
        )
        raise InputDataError(f"output folder {folder} {state}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputDataError(f"output folder {folder} is not writable; choose another")


def check_output_folder(path: str | os.PathLike[str]) -> Path:
    """``path`` as a folder to write files into (made if its parent exists), or the
    one-line error: a file named where a folder is wanted, or a missing parent."""
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise InputDataError(f"{target} is a file; name a folder to write the figures into")
    _check_writable_folder(target if target.exists() else target.parent)
    return target


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file and a rename.

    A crash or an error leaves either the old file or the new one, never half.
    """
    target = check_output_file(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as handle:
            handle.write(text)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual mode
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
