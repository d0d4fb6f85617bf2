"""``surrogate report``: one self-contained HTML page of a study, to sign off.

- :mod:`._findings`: what the study's storage holds, read by each command's own
  reader (nothing is written there);
- :mod:`._solvers`: the full solver's version, settings and verification figures;
- :mod:`._html`: the page (plotly's JavaScript embedded once: it opens offline);
- :mod:`._report`: ``report`` — checks, the atomic write, the dashboard artifact.
"""

from ._report import ReportResult, report

__all__ = ["ReportResult", "report"]
