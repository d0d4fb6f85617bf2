"""Exception types of the product.

Each subclasses the built-in exception a caller would catch anyway, so code
that knows nothing of this package still handles them (BoTorch's habit).
"""

from __future__ import annotations

__all__ = ["InputDataError", "InputDataWarning", "Interrupted", "SolverError", "SurrogateError"]


class SurrogateError(Exception):
    """Base class of every error this package raises on purpose."""


class InputDataError(SurrogateError, ValueError):
    """A user-supplied value, option or file is invalid.

    The message is one line: what is wrong, the value seen, and how to fix it.
    """


class InputDataWarning(UserWarning):
    """User-supplied data is odd but usable (e.g. forces of thousands of N in a file
    stated in N); the message is one line saying what looks wrong and the fix."""


class SolverError(SurrogateError, RuntimeError):
    """A full-solver run did not produce a trustworthy curve.

    Raised instead of returning a wrong curve (e.g. Newton did not converge at
    some angle). The message names the angle and the likely cause.
    """


class Interrupted(SurrogateError):
    """A signal (SIGTERM, SIGINT) stopped the command; ``signal_name`` names it.

    What was finished is in the storage; the message says how to resume.
    """

    def __init__(self, signal_name: str, message: str) -> None:
        super().__init__(message)
        self.signal_name = signal_name
