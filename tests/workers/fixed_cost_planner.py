"""``surrogate run`` whose local workers solve with the fixed-cost stand-in.

Run: ``python -m tests.workers.fixed_cost_planner LOG COST_S RUN-ARGS…`` (the arguments of
``surrogate run``); the planner's :class:`~surrogate.identify._worker.WorkerDispatcher`
gets :class:`tests.workers.fixed_cost.FixedCostSolve` as its solver, so a test can stop
the planner while its worker processes solve. Selectable only from code, as the stand-in.
"""

from __future__ import annotations

import sys
from typing import Any

from tests.workers.fixed_cost import FixedCostSolve


def main(argv: list[str]) -> int:
    from surrogate._cli import main as surrogate_main
    from surrogate.identify import _worker

    log, cost_s, *run_args = argv
    start = _worker.WorkerDispatcher.__init__

    def init(self: Any, *args: Any, **kwargs: Any) -> None:
        start(self, *args, **{**kwargs, "solve": FixedCostSolve(log, float(cost_s))})

    _worker.WorkerDispatcher.__init__ = init  # type: ignore[method-assign]
    return surrogate_main(["run", *run_args])


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
