"""Progress of long runs through :mod:`logging` (logger ``surrogate``), on stderr by default.

Every module logs to ``logging.getLogger(__name__)``; a command or an API call
with ``progress=True`` makes sure the messages are seen: it gives the
``surrogate`` logger a stderr handler at INFO unless the application configured
one (then its handlers and levels decide). Messages are one line, prefixed with
the study's name in brackets.
"""

from __future__ import annotations

import logging
import sys

__all__ = ["LOGGER_NAME", "drop_ctrl_c_echoes", "show_progress"]

LOGGER_NAME = "surrogate"
_HANDLER_NAME = "surrogate-progress"


def show_progress() -> None:
    """A stderr handler at INFO on the ``surrogate`` logger, once (idempotent)."""
    logger = logging.getLogger(LOGGER_NAME)
    if any(h.get_name() == _HANDLER_NAME for h in logger.handlers):
        return
    if logger.handlers or logging.getLogger().handlers:
        return  # the application decides where logging goes
    handler = logging.StreamHandler(sys.stderr)
    handler.set_name(_HANDLER_NAME)
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger.addHandler(handler)
    if logger.level == logging.NOTSET or logger.level > logging.INFO:
        logger.setLevel(logging.INFO)
    logger.propagate = False


def drop_ctrl_c_echoes() -> None:
    """For a command: Python's last-resort output (stderr, where nothing configured logging)
    leaves out SQLAlchemy's records that a Ctrl-C set off — after a SIGINT inside a query it
    logs "Error closing cursor" with two tracebacks above the command's one line. Every other
    record goes where it went. Idempotent."""
    if logging.lastResort is not None and _not_ctrl_c not in logging.lastResort.filters:
        logging.lastResort.addFilter(_not_ctrl_c)


def _not_ctrl_c(record: logging.LogRecord) -> bool:
    """False for a record of SQLAlchemy's whose exception a KeyboardInterrupt set off
    (anywhere in its chain, a context suppressed with ``from None`` too)."""
    if not record.name.startswith("sqlalchemy"):
        return True
    error = record.exc_info[1] if record.exc_info else None
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return False
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return True
