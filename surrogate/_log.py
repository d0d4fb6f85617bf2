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
_ECHOES_NAME = "surrogate-no-ctrl-c-echoes"


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
    """For a command: a log record of the database library's (SQLAlchemy's) whose exception
    a Ctrl-C set off is dropped; every other goes where it went, to Python's last-resort
    handler (stderr, WARNING and up). A Ctrl-C during a query makes SQLAlchemy close the
    connection, then fail to close its cursor, and log "Error closing cursor" with two
    tracebacks — above the one line the command prints (``surrogate run``'s Ctrl-C test,
    three pytest processes on two cores). Idempotent; nothing where the application
    configured logging."""
    logger = logging.getLogger("sqlalchemy")
    if any(h.get_name() == _ECHOES_NAME for h in logger.handlers):
        return
    if logger.handlers or logging.getLogger().handlers:
        return  # the application decides where logging goes
    handler = _LastResortUnlessCtrlC()
    handler.set_name(_ECHOES_NAME)
    logger.addHandler(handler)


class _LastResortUnlessCtrlC(logging.Handler):
    """:data:`logging.lastResort`, for the records no Ctrl-C set off."""

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        seen: set[int] = set()
        while error is not None and id(error) not in seen:
            if isinstance(error, KeyboardInterrupt):
                return False
            seen.add(id(error))
            error = error.__cause__ or error.__context__
        return bool(super().filter(record))

    def emit(self, record: logging.LogRecord) -> None:
        if logging.lastResort is not None:
            logging.lastResort.handle(record)
