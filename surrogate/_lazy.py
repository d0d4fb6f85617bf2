"""Names a package loads on first use (PEP 562), so importing it stays light.

scikit-learn, Optuna and pandas take seconds to import; ``surrogate --help``,
``surrogate simulate`` and the solvers do not need them.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from importlib import import_module
from typing import Any

__all__ = ["lazy_attributes"]


def lazy_attributes(
    package: str, modules: Mapping[str, str], public: Sequence[str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` of ``package``: each name of ``modules`` is imported
    from its (relative) module when first asked for, then kept in the package."""

    def __getattr__(name: str) -> Any:
        if name in modules:
            value = getattr(import_module(modules[name], package), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(public)

    return __getattr__, __dir__
