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

__all__ = ["LOGGER_NAME", "show_progress"]

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
