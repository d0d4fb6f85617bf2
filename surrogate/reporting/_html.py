"""The report as one self-contained HTML page.

It opens with no network: plotly's JavaScript is embedded once, with the first
figure, and every later figure uses it. Every text from the study or the storage
is escaped. Sections come in the order an engineer signs off: the study, the
solver, what was identified or calibrated, the curves against the target or the
measurements, the diagnosis, the LS-DYNA snippet; a section without data says so
in one sentence.
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from ..calibration._compare import comparison_figures
from ..calibration._determination import interval_text, parameter_interval_text
from ..calibration._diagnose import ladder_figure
from ..calibration._statistics import ranking_label
from ..storage._dashboard import verified_curves_figure
from ..storage._storage import redacted_url
from ..study._design import conditions_text
from ._findings import Calibration, Findings, Identification
from ._solvers import solver_facts

__all__ = ["render"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2rem auto; max-width: 72rem; color: #222;
       padding: 0 1rem; }
h1 { font-size: 1.6rem; } h2 { border-bottom: 1px solid #ccc; margin-top: 2.2rem; }
table { border-collapse: collapse; margin: 0.6rem 0 1rem; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.6rem; text-align: left; vertical-align: top; }
th { background: #f2f2f2; }
.missing { color: #8a4b00; font-style: italic; } .warning { color: #b00020; }
pre { background: #f6f6f6; padding: 0.8rem; overflow-x: auto; }
.figure { margin: 1rem 0; }
"""


class _Figures:
    """Plotly figures as HTML; the first embeds plotly's JavaScript for all."""

    def __init__(self) -> None:
        self.embedded = False

    def __call__(self, figure: Any) -> str:
        text = figure.to_html(
            full_html=False,
            include_plotlyjs=not self.embedded,
            config={"displaylogo": False, "responsive": True},
        )
        self.embedded = True
        return f'<div class="figure">{text}</div>'


def render(findings: Findings, *, generated: str, version: str) -> str:
    """The page of ``findings`` (``generated``: when, ``version``: the package's)."""
    figures = _Figures()
    spec = findings.spec
    body = [
        f"<h1>Coating report: {_e(spec.name)}</h1>",
        _table(
            ["", ""],
            [
                ["study file", _e(spec.path.resolve() if spec.path else "(in memory)")],
                ["storage", _e(redacted_url(findings.storage))],
                ["made", _e(f"{generated} by surrogate {version} (surrogate report)")],
            ],
            head=False,
        ),
        _study(findings),
        _solver(findings),
        _identification(findings, figures),
        _calibration(findings),
        _comparison(findings, figures),
        _diagnosis(findings, figures),
        _next_test(findings),
        _export(findings),
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>Coating report: {_e(spec.name)}</title>\n<style>{_STYLE}</style>\n"
        "</head>\n<body>\n" + "\n".join(body) + "\n</body>\n</html>\n"
    )


# -- pieces --------------------------------------------------------------------------------------
def _e(value: Any) -> str:
    return html.escape(str(value))


def _num(value: Any, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return _e(value)
    return f"{value:.{digits}g}"


def _table(headers: Sequence[str], rows: Iterable[Sequence[str]], *, head: bool = True) -> str:
    """A table of already escaped cells."""
    top = "<tr>" + "".join(f"<th>{_e(h)}</th>" for h in headers) + "</tr>" if head else ""
    lines = ["<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" for row in rows]
    return "<table>" + top + "".join(lines) + "</table>"


def _section(anchor: str, title: str, *parts: str) -> str:
    return f'<section id="{anchor}"><h2>{_e(title)}</h2>\n' + "\n".join(parts) + "</section>"


def _p(text: str, cls: str = "") -> str:
    return f'<p class="{cls}">{_e(text)}</p>' if cls else f"<p>{_e(text)}</p>"


def _pairs(items: Mapping[str, Any]) -> str:
    return _table(["", ""], [[_e(k), _num(v)] for k, v in items.items()], head=False)


# -- the study and the solver --------------------------------------------------------------------
def _study(findings: Findings) -> str:
    spec = findings.spec
    targets = (
        f"F60 = {spec.targets.f60_n:.4g} N ± {100 * spec.targets.tolerance:g} %"
        if spec.targets.f60_n
        else "none (measured curves only)"
    )
    constraints = spec.constraints
    parts = [
        _pairs(
            {
                "seed": spec.seed,
                "target": targets,
                "θsat at least [deg]": constraints.theta_sat_deg_min,
                "Tcoat at most [fraction of the thickness]": (
                    constraints.tcoat_max_fraction_of_thickness
                ),
                "preferred low, first first": ", ".join(spec.preference_order),
                "effects of the model": ", ".join(spec.effects) or "none (base model)",
                "measured curves": spec.measurements_file or "none",
            }
        ),
        "<h3>Parameter ranges</h3>",
        _table(
            ["parameter", "low", "high", "unit", "log scale"],
            [[_e(p.name), _num(p.low), _num(p.high), _e(p.unit), _e(p.log)] for p in spec.space],
        ),
        "<h3>Rig</h3>",
        _pairs(spec.rig.to_dict()),
        _tests(findings),
    ]
    return _section("study", "The study", *parts)


def _tests(findings: Findings) -> str:
    data = findings.measurements
    if data is None:
        reason = findings.missing.get("measurements")
        return _p(reason, "missing") if reason else ""
    columns = [*data.conditions, *data.covariates]
    rows = []
    for row in data.tests.to_dict("records"):
        curve = data.curves[data.curves.test_id == row["test_id"]]
        angles = f"{curve.angle_deg.min():g}–{curve.angle_deg.max():g}"
        rows.append([_e(row["test_id"]), *(_num(row[c]) for c in columns), str(len(curve)), angles])
    noise = findings.spec.noise_n
    said = (
        f"noise stated in the study: {noise:.4g} N"
        if noise is not None
        else f"noise from the replicates: {_num(data.noise_n)} N ({data.noise_dof} d.o.f.)"
    )
    return (
        "<h3>Measured tests</h3>"
        + _table(["test", *columns, "points", "angles [deg]"], rows)
        + _p(said)
    )


def _solver(findings: Findings) -> str:
    facts = solver_facts(findings.spec)
    parts = [
        _pairs(
            {
                "solver": facts.kind,
                "version": facts.version,
                "settings that name a run": _settings(facts.result_settings),
                "settings that say how to run": _settings(facts.run_settings),
            }
        )
    ]
    identification = findings.identification
    if identification is not None and identification.differs:
        parts.append(
            _p(
                f"The study file differs from the runs in the storage: {identification.differs}",
                "warning",
            )
        )
    if facts.figures:
        parts += [
            _p(f"Verification of {facts.kind} {facts.version} ({facts.source}):"),
            _table(
                ["check", "measured", "target"],
                [[_e(c), _e(m), _e(t or "—")] for c, m, t in facts.figures],
            ),
        ]
    if facts.remark:
        parts.append(_p(facts.remark, "missing" if not facts.figures else ""))
    return _section("solver", "The full solver", *parts)


def _settings(settings: Mapping[str, Any]) -> str:
    return ", ".join(f"{k} = {v}" for k, v in settings.items()) or "none"


# -- identification ------------------------------------------------------------------------------
def _identification(findings: Findings, figures: _Figures) -> str:
    found = findings.identification
    title = "Identified coating (surrogate run)"
    if found is None:
        return _section("identification", title, _p(findings.missing["identification"], "missing"))
    ok = [r for r in found.records if r.ok]
    point = found.chosen or found.best
    parts = [
        _p(found.result["message"] if found.result else _status(found)),
        _p(
            f"{len(found.records)} full-solver runs in {found.study!r}: {len(ok)} succeeded, "
            f"{len(found.records) - len(ok)} failed."
        ),
    ]
    if point is not None:
        label = (
            "chosen verified point" if found.chosen else "best verified point (misses the target)"
        )
        parts += [f"<h3>{_e(label)}</h3>", _point(point)]
    parts.append(
        _p(f"What the target determines: {found.identifiability}")
        if found.identifiability
        else _p("No identifiability statement is stored for this run.", "missing")
    )
    if ok:
        spec = found.spec
        figure = verified_curves_figure(
            found.records,
            target_n=float(spec.targets.f60_n or 0.0),
            tolerance=spec.targets.tolerance,
            chosen_number=None if found.chosen is None else found.chosen.number,
        )
        parts.append(figures(figure))
    return _section("identification", title, *parts)


def _status(found: Identification) -> str:
    if found.chosen is not None:
        return "verified: a full-solver run meets the target and every constraint"
    return "no verified point meets the target and every constraint yet"


def _point(point: Any) -> str:
    values = {
        **{f"{k}": v for k, v in point.params.items()},
        "F60 [N]": point.f60_n,
        "θsat [deg]": point.theta_sat_deg,
        "misfit |F60/target − 1|": point.misfit,
        **{f"constraint {k} (≤ 0 holds)": v for k, v in point.constraints.items()},
        "verify trial": point.number,
    }
    return _pairs(values)


# -- calibration ---------------------------------------------------------------------------------
def _calibration(findings: Findings) -> str:
    found = findings.calibration
    title = "Calibrated coating (surrogate calibrate)"
    if found is None:
        return _section("calibration", title, _p(findings.missing["calibration"], "missing"))
    record = found.record
    summary = {
        "model": f"{found.model} — {found.why}",
        "status": record["status"],
        "RMSE [N]": record["rmse_n"],
        "noise [N]": record["noise_n"],
        "RMSE / noise": record["rmse_n"] / record["noise_n"],
        "misfit against the noise": (
            f"{record['misfit']} (F-test p = {record['misfit_p_value']:.2g})"
            if record.get("misfit")
            else "not stated (not converged)"
        ),
        "full-solver runs": record["solver_calls"],
    }
    parts = [_p(record["message"]), _pairs(summary), _determination(record)]
    per_test = record.get("rmse_per_test_n") or {}
    if per_test:
        parts += [
            "<h3>RMSE per test at the calibrated point</h3>",
            _table(["test", "RMSE [N]"], [[_e(k), _num(v)] for k, v in per_test.items()]),
        ]
    return _section("calibration", title, *parts)


def _determination(record: Mapping[str, Any]) -> str:
    """The parameters with their 95 % intervals, and D and Mp, or why there are none."""
    determination = record.get("determination")
    rows = []
    for name, value in record["params"].items():
        span = "—" if determination is None else parameter_interval_text(name, determination)
        rows.append([_e(name), _num(value), _e(span)])
    for key, c in ((determination or {}).get("combinations") or {}).items():
        rows.append([_e(key), _num(c["value"]), _e(interval_text(c))])
    parts = ["<h3>Parameters and what the curves determine</h3>"]
    parts.append(_table(["quantity", "value", "95 % interval"], rows))
    if determination is None:
        hint = (
            "raise --budget"
            if record.get("status") == "budget_exhausted"
            else "it stopped with runs left: its message says why"
        )
        parts.append(
            _p(
                "No intervals: the calibration did not converge to a verified local optimum, "
                f"so the data's determination was not assessed ({hint}).",
                "missing",
            )
        )
    else:
        parts.append(_p(determination["statement"]))
    return "\n".join(parts)


# -- measured against model ----------------------------------------------------------------------
def _comparison(findings: Findings, figures: _Figures) -> str:
    found = findings.comparison
    title = "Measured against model curves"
    if found is None:
        return _section("comparison", title, _p(findings.missing["comparison"], "missing"))
    result = found.result
    columns = [*found.problem.data.conditions, *found.problem.data.covariates]
    tests = [
        [_e(t["test_id"]), *(_num(t[c]) for c in columns), _num(t["rmse_n"]), _num(t["bias_n"])]
        for t in result.tests
    ]
    bands = [
        [_e(b["band"]), _num(b["rmse_n"]), _num(b["bias_n"]), str(b["points"])]
        for b in result.bands
    ]
    parts = [
        _p(result.message),
        *(figures(f) for f in comparison_figures(found).values()),
        "<h3>Residual (measured − model) by test</h3>",
        _table(["test", *columns, "RMSE [N]", "mean [N]"], tests),
        "<h3>By angle band</h3>",
        _table(["band", "RMSE [N]", "mean [N]", "points"], bands),
    ]
    if result.covariates:
        parts += [
            "<h3>By condition and covariate</h3>",
            _table(
                ["column", "correlation with the tests' mean residual"],
                [[_e(k), _num(v, 2)] for k, v in result.covariates.items()],
            ),
        ]
    return _section("comparison", title, *parts)


# -- diagnosis -----------------------------------------------------------------------------------
def _diagnosis(findings: Findings, figures: _Figures) -> str:
    found = findings.calibration
    title = "Diagnosis and model ladder (surrogate diagnose)"
    parts = []
    if found is None or (found.diagnosis is None and found.verdict is None):
        parts.append(_p(findings.missing["diagnosis"], "missing"))
    else:
        parts += _verdict(found)
    if found is not None:
        parts += [
            "<h3>Model ladder (every calibration in this storage)</h3>",
            _table(
                ["model", "RMSE [N]", "held-out RMSE [N]", "noise [N]", "full-solver runs"],
                [
                    [
                        _e(s["model"]),
                        _num(s["rmse_n"]),
                        _num(s["heldout_rmse_n"]),
                        _num(s["noise_n"]),
                        str(s["solver_calls"]),
                    ]
                    for s in found.ladder
                ],
            ),
        ]
        if len(found.ladder) > 1:
            parts.append(figures(ladder_figure(found.ladder, found.ladder[0]["noise_n"])))
    return _section("diagnosis", title, *parts)


def _verdict(found: Calibration) -> list[str]:
    parts = [_p(f"Verdict on model {found.model}: {found.verdict}")]
    diagnosis = found.diagnosis
    if diagnosis is None:
        return parts
    parts.append(
        _table(
            ["added effect", "RMSE [N]", "held-out RMSE [N]", "ΔBIC"],
            [
                [
                    _e(ranking_label(e)),
                    _num(e["rmse_n"]),
                    _num(e["heldout_rmse_n"]),
                    _num(e["delta_bic"], 3),
                ]
                for e in diagnosis["ranking"]
            ],
        )
    )
    if diagnosis.get("tied_with"):
        parts.append(
            _p(
                "As good as the first (these data cannot tell them apart): "
                + ", ".join(diagnosis["tied_with"])
            )
        )
    where = [f"{c['kind']} {c['name']} (RMSE {c['rmse_n']:.3g} N)" for c in diagnosis["where"]]
    if where:
        parts.append(_p("Where the model fails: " + "; ".join(where)))
    follows = [f["covariate"] for f in diagnosis["follows"] if f.get("significant")]
    parts.append(_p("The residual follows: " + (", ".join(follows) or "nothing recorded")))
    return parts


def _next_test(findings: Findings) -> str:
    """The stored ``next-test`` recommendation of the shown model: its message (which
    names the effects the data cannot test and the pairs no test tells apart) and the
    ranked tests with what each settles of the goal; said to be stale where the data
    changed since."""
    title = "Next test (surrogate next-test)"
    found = findings.calibration
    record = found.next_test if found is not None else None
    if found is None or record is None:
        return _section("next_test", title, _p(findings.missing["next_test"], "missing"))
    parts = [_p(record["message"])]
    if record.get("data_sha256") != found.data_sha256:
        parts.append(
            _p(
                "Made on other measurements than the calibration shown (tests were added or "
                f"changed since): run `surrogate next-test {findings.spec.path}` again.",
                "missing",
            )
        )
    goal = record["goal"]
    rows = [(str(rank), entry) for rank, entry in enumerate(record["recommended"], 1)]
    if record.get("reference") is not None:
        rows.append(("reference", record["reference"]))
    if rows and goal:
        parts.append(
            _table(
                ["rank", "test", "replicates", f"{goal} after (95 %)", "also settles"],
                [
                    [
                        rank,
                        _e(conditions_text(entry["conditions"])),
                        str(entry["replicates"]),
                        _e(entry["predicted"][goal]["precision"]),
                        _e(", ".join(n for n in entry["settles"] if n != goal) or "—"),
                    ]
                    for rank, entry in rows
                ],
            )
        )
    notes = "; ".join(record["notes"])
    parts.append(_p(f"({notes + '; ' if notes else ''}{record['candidates']} candidate tests)"))
    return _section("next_test", title, *parts)


# -- the keyword snippet -------------------------------------------------------------------------
def _export(findings: Findings) -> str:
    title = "LS-DYNA keyword snippet (surrogate export)"
    if findings.export_text is None:
        return _section("export", title, _p(findings.missing["export"], "missing"))
    return _section(
        "export",
        title,
        _p("Units mm-N-s (MPa); `surrogate export` writes other unit systems."),
        f"<pre>{_e(findings.export_text)}</pre>",
    )
