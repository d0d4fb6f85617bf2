"""Which test to run next (``surrogate next-test``): candidate tests inside the study's
``[design]``, what each would settle of what the calibration's intervals leave open,
which effects it tells apart, and which effects the data cannot test at all.

- ``_candidates`` — the candidate tests: a factorial of the conditions ``[design]`` lets
  the lab vary;
- ``_information`` — pure numerics: what a test's replicates add between two fits'
  curves, how a profile side moves in, when two fits are told apart;
- ``_next_test`` — the command: the calibration's profile re-fits (its alternatives)
  and the diagnosis's leaders run at every candidate, ranked.
"""

from ._next_test import NextTestResult, next_test

__all__ = ["NextTestResult", "next_test"]
