"""The ``surrogate`` command: thin, each command parses, calls the API, prints.

Each command is a pair: ``_add_<command>(subparsers)`` declares its arguments and
returns its parser, and the handler ``_<command>(args)`` that follows it calls the
Python API and prints the result. ``_COMMANDS`` lists the pairs in the order of
``surrogate --help``. Arguments that several commands take (``--json``,
``--storage``, ``--plugin``, ``--effect``) are declared once, in a helper each.

Errors are one line on stderr with exit code 2; nothing is half-written.
Progress of long runs goes through :mod:`logging` (see :mod:`surrogate._log`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, NoReturn

from ._errors import InputDataError, InputDataWarning, Interrupted, SolverError
from ._io import atomic_write_text
from ._log import drop_ctrl_c_echoes, show_progress
from .solvers import available_solvers
from .solvers._simulate import BendingCurve, simulate
from .study._rig import Rig
from .study._space import DESIGNS

__all__ = ["main"]

EXIT_USAGE = 2
EXIT_SOLVER = 3

_Subparsers = argparse._SubParsersAction  # what ``add_subparsers`` returns
_Handler = Callable[[argparse.Namespace], int]


class _OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line (argparse prints the whole usage)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


# Arguments that several commands share -------------------------------------------------


def _add_json(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _add_storage(
    parser: argparse.ArgumentParser,
    help: str = "Optuna storage URL (default: SQLite next to the study)",
    required: bool = False,
) -> None:
    parser.add_argument("--storage", required=required, help=help)


def _add_plugin(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--plugin",
        action="append",
        default=[],
        metavar="MODULE",
        help="import a module of your own effects first (repeatable)",
    )


def _add_model_options(parser: argparse.ArgumentParser) -> None:
    """``--effect NAME`` (the model's effects) and ``--plugin`` of the calibration commands."""
    parser.add_argument(
        "--effect",
        action="append",
        default=None,
        metavar="NAME",
        help="an effect of the model (repeatable; default: the study's [model] effects)",
    )
    _add_plugin(parser)


def _add_launcher(parser: argparse.ArgumentParser, runs: str) -> None:
    """``--launcher NAME`` (a batch scheduler runs ``runs``, one a job) and ``--heartbeat``."""
    from .cluster import available_launchers

    parser.add_argument(
        "--launcher",
        choices=available_launchers(),
        help=f"a batch scheduler runs {runs}, one run a job, as [cluster] says "
        "(docs/guides/clusters.md); the storage must be one its nodes reach",
    )
    parser.add_argument(
        "--heartbeat",
        type=int,
        default=10,
        help="heartbeat interval of the workers in s (default 10); a run silent for three "
        "is retried",
    )


def _print_json(payload: Any) -> None:
    print(json.dumps(payload, allow_nan=True))


# surrogate simulate --------------------------------------------------------------------


def _add_simulate(commands: _Subparsers) -> argparse.ArgumentParser:
    sim = commands.add_parser("simulate", help="run the full solver for one coating")
    sim.add_argument("--ecoat", type=float, required=True, help="coat Young's modulus [GPa]")
    sim.add_argument("--scoat", type=float, required=True, help="coat yield stress [GPa]")
    sim.add_argument("--tcoat", type=float, required=True, help="coat thickness [mm]")
    _add_rig_options(sim)
    sim.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME[:P=V,...]",
        help="switch on a physical effect, e.g. hardening:ratio=0.05 (repeatable)",
    )
    sim.add_argument(
        "--condition",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a test condition, e.g. direction=weft, tension_n=20 (repeatable)",
    )
    _add_plugin(sim)
    sim.add_argument(
        "--solver",
        choices=available_solvers(),
        default="builtin",
        help="full solver (default: builtin)",
    )
    sim.add_argument(
        "--solver-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a setting of an external solver, e.g. mesh=fine, timeout_s=600 (repeatable)",
    )
    sim.add_argument("--out", type=Path, help="write angle_deg,force_n,force_perp_n to this CSV")
    _add_json(sim)
    return sim


def _simulate(args: argparse.Namespace) -> int:
    from .effects import load_plugin

    for module in args.plugin:
        load_plugin(module)
    curve = simulate(
        args.ecoat,
        args.scoat,
        args.tcoat,
        rig=_rig_from(args),
        effects=_parse_effects(args.effect),
        conditions=_parse_conditions(args.condition),
        solver=args.solver,
        solver_settings=_parse_solver_options(args.solver_option),
    )
    if args.out is not None:
        atomic_write_text(args.out, _curve_csv(curve))
    if args.json:
        _print_json(curve.to_json())
    else:
        print(_curve_table(curve))
        if args.out is not None:
            print(f"curve written to {args.out}")
    return 0


def _add_rig_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("rig (defaults: design.md §3)")
    default = Rig()
    for flag, field, unit in (
        ("--thickness", "thickness_mm", "mm"),
        ("--width", "width_mm", "mm"),
        ("--bending-length", "bending_length_mm", "mm"),
        ("--probe-radius", "probe_radius_mm", "mm"),
        ("--free-length", "free_length_mm", "mm"),
        ("--friction", "friction", ""),
        ("--max-angle", "max_angle_deg", "deg"),
        ("--element-size", "element_size_mm", "mm"),
        ("--tension", "tension_n", "N"),
    ):
        value = getattr(default, field)
        shown = "graded mesh" if value is None else f"{value:g} {unit}".strip()
        group.add_argument(
            flag, dest=field, type=float, default=value, help=f"{field} (default: {shown})"
        )


def _rig_from(args: argparse.Namespace) -> Rig:
    fields = Rig.__dataclass_fields__
    return Rig(**{name: getattr(args, name) for name in fields})


def _parse_effects(items: list[str]) -> dict[str, dict[str, float]]:
    effects: dict[str, dict[str, float]] = {}
    for item in items:
        name, _, rest = item.partition(":")
        values: dict[str, float] = {}
        for pair in filter(None, rest.split(",")):
            key, sep, value = pair.partition("=")
            if not sep:
                raise InputDataError(
                    f"--effect {item!r}: expected NAME:P=V[,P=V], e.g. hardening:ratio=0.05"
                )
            try:
                values[key.strip()] = float(value)
            except ValueError:
                raise InputDataError(
                    f"--effect {item!r}: {key} must be a number, got {value!r}"
                ) from None
        effects[name.strip()] = values
    return effects


def _parse_conditions(items: list[str], option: str = "--condition") -> dict[str, object]:
    """``NAME=VALUE`` items (a value a number where it reads as one)."""
    conditions: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise InputDataError(f"{option} {item!r}: expected NAME=VALUE, e.g. direction=weft")
        try:
            conditions[key.strip()] = float(value)
        except ValueError:
            conditions[key.strip()] = value.strip()
    return conditions


def _parse_solver_options(items: list[str]) -> dict[str, object]:
    options: dict[str, object] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise InputDataError(f"--solver-option {item!r}: expected KEY=VALUE, e.g. mesh=fine")
        value: object = text.strip()
        if text.strip().lower() in ("true", "false"):
            value = text.strip().lower() == "true"
        else:
            for kind in (int, float):
                try:
                    value = kind(text)
                    break
                except ValueError:
                    pass
        options[key.strip()] = value
    return options


def _curve_csv(curve: BendingCurve) -> str:
    rows = ["angle_deg,force_n,force_perp_n"]
    rows += [
        f"{a:g},{f:.6g},{p:.6g}"
        for a, f, p in zip(curve.angle_deg, curve.force_n, curve.force_perp_n, strict=True)
    ]
    return "\n".join(rows) + "\n"


def _curve_table(curve: BendingCurve) -> str:
    lines = [
        f"Ecoat {curve.ecoat_gpa:g} GPa, Scoat {curve.scoat_gpa:g} GPa, "
        f"Tcoat {curve.tcoat_mm:g} mm",
        f"{'angle_deg':>9} {'force_n':>9} {'force_perp_n':>12}",
    ]
    for a, f, p in zip(curve.angle_deg, curve.force_n, curve.force_perp_n, strict=True):
        if a % 10 == 0 or a == curve.angle_deg[-1]:
            lines.append(f"{a:9.0f} {f:9.3f} {p:12.3f}")
    state = "saturated" if curve.saturated else "not saturated within the range"
    lines.append(f"F60 = {curve.f60_n:.4g} N, theta_sat = {curve.theta_sat_deg:g} deg ({state})")
    return "\n".join(lines)


# surrogate doe -------------------------------------------------------------------------


def _add_doe(commands: _Subparsers) -> argparse.ArgumentParser:
    design = commands.add_parser("doe", help="make a design of experiments, optionally run it")
    design.add_argument(
        "--design",
        choices=DESIGNS,
        default="lhs",
        help="factorial (--n levels per parameter), lhs, sobol, or paper "
        "(the paper's 64 Table-1 cases)",
    )
    design.add_argument("--n", type=int, default=16, help="points (levels for factorial)")
    design.add_argument("--seed", type=int, default=None, help="seed (default: the study's, or 0)")
    design.add_argument("--study", type=Path, help="take ranges and rig from this study file")
    design.add_argument(
        "--from",
        dest="points_file",
        type=Path,
        help="take the points from this CSV instead (parameter columns)",
    )
    design.add_argument("--run", action="store_true", help="run the full solver on the design")
    design.add_argument("--jobs", type=int, default=1, help="worker processes for --run")
    design.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="result cache folder (default: .solver-cache next to --out)",
    )
    design.add_argument("--out", type=Path, required=True, help="CSV to write")
    _add_plugin(design)
    _add_json(design)
    return design


def _doe(args: argparse.Namespace) -> int:
    from .identify._commands import doe

    result = doe(
        args.design,
        n=args.n,
        seed=args.seed,
        study=args.study,
        run=args.run,
        jobs=args.jobs,
        out=args.out,
        cache_dir=args.cache,
        points_file=args.points_file,
        plugins=args.plugin,
        progress=not args.json and sys.stderr.isatty(),
    )
    if args.json:
        _print_json(result.to_json())
        return 0
    print(f"{result.design} design: {result.n_points} points written to {result.out}")
    if result.ran:
        print(
            f"solver runs: {result.n_ok} ok, {result.n_failed} failed; "
            f"{result.solver_calls} solved now, {result.cached} from the cache"
        )
    return 0


# surrogate fit -------------------------------------------------------------------------


def _add_fit(commands: _Subparsers) -> argparse.ArgumentParser:
    fitting = commands.add_parser("fit", help="fit the GP surrogates to a sample set")
    fitting.add_argument("samples", type=Path, help="sample set CSV (from doe --run)")
    fitting.add_argument("--out", type=Path, help="model JSON to write")
    fitting.add_argument("--seed", type=int, default=0, help="seed of the optimiser restarts")
    _add_json(fitting)
    return fitting


def _fit(args: argparse.Namespace) -> int:
    from .gp import cross_validation_table
    from .identify._commands import fit

    result = fit(args.samples, out=args.out, seed=args.seed)
    if args.json:
        _print_json(result.to_json())
        return 0
    print(
        f"fitted on {result.n_train} successful runs"
        + (f"; model written to {result.model}" if result.model else "")
    )
    print(cross_validation_table({"f60_n": result.f60_n, "theta_sat_deg": result.theta_sat_deg}))
    return 0


# surrogate predict ---------------------------------------------------------------------


def _add_predict(commands: _Subparsers) -> argparse.ArgumentParser:
    prediction = commands.add_parser("predict", help="predict F60 and theta_sat at points")
    prediction.add_argument("model", type=Path, help="model JSON (from fit)")
    prediction.add_argument("points", type=Path, help="CSV with the parameter columns")
    prediction.add_argument("--out", type=Path, help="CSV to write (points + predictions)")
    _add_json(prediction)
    return prediction


def _predict(args: argparse.Namespace) -> int:
    from .identify._commands import predict

    result = predict(args.model, args.points, out=args.out)
    if args.json:
        _print_json(result.to_json())
        return 0
    for row in result.predictions[:20]:
        print(", ".join(f"{k}={v:.4g}" for k, v in row.items()))
    if result.n_points > 20:
        print(f"… {result.n_points - 20} more")
    if result.out:
        print(f"predictions written to {result.out}")
    return 0


# surrogate run -------------------------------------------------------------------------


def _add_run(commands: _Subparsers) -> argparse.ArgumentParser:
    running = commands.add_parser(
        "run", help="the main job: find the coating that meets the study's target"
    )
    running.add_argument("study", type=Path, help="study file (studies/*.toml)")
    _add_storage(running)
    running.add_argument("--seed", type=int, help="override [study] seed")
    running.add_argument("--target", type=_target, help="override the target: f60_n=VALUE")
    running.add_argument("--budget", type=int, help="override [budget] max_solver_calls")
    running.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="N local worker processes verify through the storage (journal or PostgreSQL); "
        "0: queue the runs for `surrogate worker` processes elsewhere (default 1)",
    )
    _add_storage_patience(running, "the planner (--jobs N != 1)")
    _add_launcher(running, "every verification")
    _add_json(running)
    return running


def _run(args: argparse.Namespace) -> int:
    from .study._spec import load_study

    spec = load_study(args.study)  # a bad study file is refused before the loop's imports (~2 s)
    from .identify._loop import run

    result = run(
        spec,
        storage=args.storage,
        seed=args.seed,
        target=args.target,
        budget=args.budget,
        jobs=args.jobs,
        **_patience(args),
        progress=not args.json,
        launcher=args.launcher,
        heartbeat_s=args.heartbeat,
    )
    if args.json:
        _print_json(result.to_json())
        return 0
    print(result.message)
    if result.verified is not None:
        v = result.verified
        label = "verified optimum" if result.status == "verified" else "best verified point"
        print(
            f"{label}: Ecoat {v['ecoat_gpa']:.4g} GPa, Scoat {v['scoat_gpa']:.4g} GPa, "
            f"Tcoat {v['tcoat_mm']:.4g} mm -> F60 {v['f60_n']:.4g} N, "
            f"theta_sat {v['theta_sat_deg']:g} deg"
        )
    if result.identifiability:
        print(result.identifiability["statement"])
    print(f"study {result.study!r} in {result.storage}")
    return 0


def _target(text: str) -> float:
    name, _, value = text.partition("=")
    if name != "f60_n" or not value:
        raise argparse.ArgumentTypeError(f"expected f60_n=VALUE, got {text!r}")
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"f60_n must be a number, got {value!r}") from None


# surrogate calibrate -------------------------------------------------------------------


def _add_calibrate(commands: _Subparsers) -> argparse.ArgumentParser:
    cal = commands.add_parser(
        "calibrate", help="fit the coating and the model's effects to the measured curves"
    )
    cal.add_argument("study", type=Path, help="study file with [measurements]")
    _add_model_options(cal)
    _add_storage(cal)
    cal.add_argument(
        "--budget", type=int, help="override [budget] calibration_solver_calls (full-solver runs)"
    )
    cal.add_argument("--jobs", type=int, default=1, help="solver processes per verification")
    _add_launcher(cal, "every run of the external full solver")
    _add_json(cal)
    return cal


def _calibrate(args: argparse.Namespace) -> int:
    from .calibration._calibrate import calibrate

    result = calibrate(  # validates --jobs and --budget (the API refuses what the CLI does)
        args.study,
        effects=args.effect,
        plugins=args.plugin,
        storage=args.storage,
        max_solver_calls=args.budget,
        jobs=args.jobs,
        progress=not args.json,
        launcher=args.launcher,
        heartbeat_s=args.heartbeat,
    )
    if args.json:
        _print_json(result.to_json())
        return 0
    print(result.message)
    print(
        "parameters (95 % interval): "
        + ", ".join(
            f"{k} = {v:.4g}{_interval(result.determination, k)}" for k, v in result.params.items()
        )
    )
    print(
        "RMSE per test [N]: " + ", ".join(f"{k} {v:.3g}" for k, v in result.rmse_per_test_n.items())
    )
    print(f"study {result.study!r} in {result.storage}")
    return 0


def _interval(determination: dict[str, Any] | None, name: str) -> str:
    """A calibrated parameter's 95 % interval as the table shows it (``" [low, high]"``,
    a one-sided bound or free, and how it was found), or what stands in for it."""
    if determination is None:
        return ""
    from .calibration._determination import parameter_interval_text

    held = " (held at its bound)" if name in determination["held_at_bound"] else ""
    return f" [{parameter_interval_text(name, determination)}]{held}"


# surrogate compare ---------------------------------------------------------------------


def _add_compare(commands: _Subparsers) -> argparse.ArgumentParser:
    comp = commands.add_parser(
        "compare", help="measured vs model curves: residuals per test, angle band, covariate"
    )
    comp.add_argument("study", type=Path, help="study file with [measurements]")
    _add_model_options(comp)
    comp.add_argument(
        "--params",
        help="parameters to compare, e.g. ecoat_gpa=1.2,scoat_gpa=0.15,tcoat_mm=0.02 "
        "(default: the last calibration of this model)",
    )
    _add_storage(comp)
    comp.add_argument("--output", type=Path, help="folder of the PNG plots")
    comp.add_argument("--no-plots", action="store_true", help="write no PNG files")
    _add_json(comp)
    return comp


def _compare(args: argparse.Namespace) -> int:
    from .calibration._compare import compare

    result = compare(
        args.study,
        params=_parse_params(args.params),
        effects=args.effect,
        plugins=args.plugin,
        storage=args.storage,
        output_dir=args.output,
        plots=not args.no_plots,
        progress=False,
    )
    if args.json:
        _print_json(result.to_json())
        return 0
    print(result.message)
    print(f"{'test':>8} {'RMSE [N]':>9} {'bias [N]':>9}")
    for test in result.tests:
        print(f"{test['test_id']:>8} {test['rmse_n']:9.4f} {test['bias_n']:+9.4f}")
    for band in result.bands:
        print(f"{band['band']:>14}: RMSE {band['rmse_n']:.4f} N over {band['points']} points")
    if result.covariates:
        print(
            "correlation of the tests' mean residual with: "
            + ", ".join(f"{k} {v:+.2f}" for k, v in result.covariates.items())
        )
    for path in result.plots:
        print(f"plot: {path}")
    return 0


# surrogate next-test -------------------------------------------------------------------


def _add_next_test(commands: _Subparsers) -> argparse.ArgumentParser:
    nxt = commands.add_parser(
        "next-test",
        help="which test inside the study's [design] settles what the data leave open",
    )
    nxt.add_argument("study", type=Path, help="study file with [measurements] and [design]")
    nxt.add_argument(
        "--goal",
        help="the quantity to settle, e.g. plastic_moment_n or tcoat_mm "
        "(default: the least determined one a test settles)",
    )
    nxt.add_argument("--count", type=int, default=3, help="recommended tests to list (default 3)")
    _add_model_options(nxt)
    _add_storage(nxt)
    nxt.add_argument("--output", type=Path, help="folder of the PNG figure")
    nxt.add_argument("--no-plots", action="store_true", help="write no PNG file")
    _add_json(nxt)
    return nxt


def _next_test(args: argparse.Namespace) -> int:
    from .design import next_test
    from .study._design import conditions_text

    result = next_test(
        args.study,
        goal=args.goal,
        count=args.count,
        effects=args.effect,
        plugins=args.plugin,
        storage=args.storage,
        output_dir=args.output,
        plots=not args.no_plots,
        progress=False,
    )
    if args.json:
        _print_json(result.to_json())
        return 0
    print(result.message)
    goal = result.goal
    if result.recommended and goal:
        rows: list[tuple[Any, dict[str, Any]]] = list(enumerate(result.recommended, 1))
        if result.reference is not None:
            rows.append(("ref", result.reference))
        tests = [conditions_text(e["conditions"]) for _, e in rows]
        wide = max(len(t) for t in tests)
        print(f"{'rank':>4}  {'test':<{wide}}  {goal + ' after (95 %)':>24}  also settles")
        for (rank, entry), test in zip(rows, tests, strict=True):
            span = entry["predicted"][goal]["precision"]
            others = ", ".join(n for n in entry["settles"] if n != goal) or "—"
            print(f"{rank!s:>4}  {test:<{wide}}  {span:>24}  {others}")
    for note in result.notes:
        print(f"({note}; {result.candidates} candidate tests, {result.solver_calls} runs)")
    if result.figure:
        print(f"figure: {result.figure}")
    return 0


def _parse_params(text: str | None) -> dict[str, float] | None:
    if text is None:
        return None
    params = {}
    for pair in filter(None, text.split(",")):
        key, sep, value = pair.partition("=")
        try:
            params[key.strip()] = float(value)
        except ValueError:
            sep = ""
        if not sep:
            raise InputDataError(
                f"--params {pair!r}: expected NAME=NUMBER[,NAME=NUMBER], e.g. ecoat_gpa=1.2"
            )
    return params


# surrogate export ----------------------------------------------------------------------


def _add_export(commands: _Subparsers) -> argparse.ArgumentParser:
    from .identify._export import EXPORT_SOURCES, TCOAT_CONVENTIONS

    exporting = commands.add_parser(
        "export", help="a verified or calibrated coating as LS-DYNA keyword text"
    )
    exporting.add_argument("study", type=Path, help="study file (after surrogate run or calibrate)")
    exporting.add_argument("--format", choices=("lsdyna",), default="lsdyna", help="output format")
    exporting.add_argument("--output", type=Path, help="write the snippet to this file")
    _add_storage(exporting, help="Optuna storage URL (default: the study's)")
    exporting.add_argument(
        "--units",
        choices=("mm-N-s", "mm-kg-ms", "m-kg-s"),
        default="mm-N-s",
        help="unit system of your deck (default mm-N-s: MPa)",
    )
    exporting.add_argument(
        "--tcoat",
        choices=tuple(TCOAT_CONVENTIONS),
        default="thickness",
        help="how TCOAT is written: thickness (> 0, read alike by every LS-DYNA version; "
        "default), bending-only (< 0, R12 / FORM -14 reading), ratio (< 0, over the "
        "shell thickness, recent manuals)",
    )
    exporting.add_argument(
        "--from",
        dest="source",
        choices=EXPORT_SOURCES,
        help="the surrogate run point or the calibration of the study's model (default: run "
        "for a study with an F60 target, else calibration)",
    )
    exporting.add_argument(
        "--at",
        default="",
        help="conditions a calibrated coat is evaluated at, e.g. tension_n=40,rate_deg_s=90",
    )
    _add_model_options(exporting)
    _add_json(exporting)
    return exporting


def _export(args: argparse.Namespace) -> int:
    from .identify._export import export

    result = export(
        args.study,
        format=args.format,
        output=args.output,
        storage=args.storage,
        units=args.units,
        tcoat=args.tcoat,
        source=args.source,
        at=_parse_conditions([item for item in args.at.split(",") if item.strip()], "--at"),
        effects=args.effect,
        plugins=args.plugin,
    )
    if args.json:
        _print_json(result.to_json())
    elif args.output is None:
        print(result.text, end="")
    else:
        what = (
            f"verify trial #{result.trial_number}"
            if result.source == "run"
            else f"the {result.status} calibration"
        )
        print(f"{what} of {result.study} written to {result.output}")
    return 0


# surrogate report ----------------------------------------------------------------------


def _add_report(commands: _Subparsers) -> argparse.ArgumentParser:
    reporting = commands.add_parser(
        "report", help="one self-contained HTML page of a study's results, to sign off"
    )
    reporting.add_argument(
        "study", type=Path, help="study file (after surrogate run, calibrate or diagnose)"
    )
    reporting.add_argument(
        "--output",
        type=Path,
        help="HTML file to write (default: <study folder>/<name>-report.html)",
    )
    _add_storage(reporting, help="Optuna storage URL (default: the study's)")
    _add_plugin(reporting)
    _add_json(reporting)
    return reporting


def _report(args: argparse.Namespace) -> int:
    from .reporting import report

    result = report(args.study, output=args.output, storage=args.storage, plugins=args.plugin)
    if args.json:
        _print_json(result.to_json())
        return 0
    print(f"report of {result.study!r} written to {result.output}")
    for sentence in dict.fromkeys(result.missing.values()):  # parts may share one reason
        print(f"  {sentence}")
    if result.attached:
        print(f"listed in the dashboard of {', '.join(map(repr, result.attached))}")
    return 0


# surrogate diagnose --------------------------------------------------------------------


def _add_diagnose(commands: _Subparsers) -> argparse.ArgumentParser:
    diag = commands.add_parser(
        "diagnose", help="where the model fails and which physical effect is missing"
    )
    diag.add_argument("study", type=Path, help="study file with [measurements]")
    _add_model_options(diag)
    _add_storage(diag)
    diag.add_argument(
        "--jobs",
        type=int,
        help="processes for the candidates' refits and an external solver's runs of one "
        "verification (default: all CPUs)",
    )
    _add_launcher(diag, "every run of the external full solver (the refits stay here)")
    _add_json(diag)
    return diag


def _diagnose(args: argparse.Namespace) -> int:
    from .calibration._diagnose import diagnose, write_ladder_plot
    from .study._spec import load_study

    result = diagnose(
        args.study,
        effects=args.effect,
        plugins=args.plugin,
        storage=args.storage,
        jobs=args.jobs,
        progress=not args.json,
        launcher=args.launcher,
        heartbeat_s=args.heartbeat,
    )
    spec = load_study(args.study)
    plot = write_ladder_plot(result.ladder, spec.directory / f"{spec.name}-compare" / "ladder.png")
    if args.json:
        _print_json(result.to_json())
        return 0
    _print_diagnosis(result)
    if plot is not None:
        print(f"plot: {plot}")
    return 0


def _print_diagnosis(result: Any) -> None:
    """The text report of a ``DiagnosisResult``: noise test, where, ranking, ladder."""
    from .calibration._statistics import ranking_label

    state = "systematic" if result.systematic else "within the noise"
    print(
        f"RMSE {result.rmse_n:.4g} N (held-out {result.heldout_rmse_n:.4g} N), noise "
        f"{result.noise_n:.4g} N: {state} (p = {result.p_value:.2g})"
    )
    for cell in result.where[:6]:
        print(f"  fails at {cell['kind']} {cell['name']}: RMSE {cell['rmse_n']:.3g} N")
    follows = [f["covariate"] for f in result.follows if f["significant"]]
    print("residual follows: " + (", ".join(follows) if follows else "nothing recorded"))
    print(f"{'added effect':>18} {'RMSE [N]':>9} {'held-out':>9} {'ΔBIC':>8}")
    for entry in result.ranking:
        print(
            f"{ranking_label(entry):>18} {entry['rmse_n']:9.4f} "
            f"{entry['heldout_rmse_n']:9.4g} {entry['delta_bic']:8.1f}"
        )
    if result.tied_with:
        tied = ", ".join(result.tied_with)
        print(f"as good as the first (these data cannot tell them apart): {tied}")
    print(result.verdict)
    print("model ladder:")
    for step in result.ladder:
        held = step["heldout_rmse_n"]
        print(
            f"  {step['model']:>18}: RMSE {step['rmse_n']:.4g} N"
            + (f", held-out {held:.4g} N" if held is not None else "")
            + f", {step['solver_calls']} solver calls"
        )


# surrogate dashboard -------------------------------------------------------------------


def _add_dashboard(commands: _Subparsers) -> argparse.ArgumentParser:
    board = commands.add_parser("dashboard", help="optuna-dashboard of a study, on 127.0.0.1")
    board.add_argument("study", type=Path, help="study file")
    _add_storage(board)
    board.add_argument("--port", type=int, default=8080, help="port on 127.0.0.1 (default 8080)")
    _add_plugin(board)
    return board


def _dashboard(args: argparse.Namespace) -> int:
    from .storage._serve import dashboard

    try:
        dashboard(args.study, storage=args.storage, port=args.port, plugins=args.plugin)
    except KeyboardInterrupt:
        pass
    return 0


# surrogate worker ----------------------------------------------------------------------


def _add_worker(commands: _Subparsers) -> argparse.ArgumentParser:
    worker = commands.add_parser(
        "worker", help="run queued verification trials of a study from a shared storage"
    )
    worker.add_argument("study", type=Path, help="the planner's study file")
    _add_storage(
        worker,
        help="postgresql://user@host/db, journal:///path/study.log (or a .log path), "
        "or sqlite:///path.db (one worker only); default: $SURROGATE_STORAGE",
    )
    worker.add_argument("--jobs", type=int, default=1, help="worker processes here (default 1)")
    worker.add_argument(
        "--max-runs",
        type=int,
        help="leave after this many runs (each process); runs of other workers then do not "
        "keep it waiting (a scheduler's job: 1)",
    )
    worker.add_argument(
        "--queue",
        choices=("verify", "runs"),
        default="verify",
        help="verify: the main job's runs (surrogate run); runs: the expensive runs of "
        "calibrate/diagnose --launcher (default verify)",
    )
    _add_plugin(worker)
    worker.add_argument(
        "--heartbeat", type=int, default=10, help="heartbeat interval in s (default 10)"
    )
    worker.add_argument(
        "--idle-timeout",
        type=float,
        default=60.0,
        help="s to wait for new trials once none is queued or running (default 60)",
    )
    _add_storage_patience(worker, "the worker")
    _add_json(worker)
    return worker


def _add_storage_patience(parser: argparse.ArgumentParser, who: str) -> None:
    parser.add_argument(
        "--storage-patience",
        type=float,
        help="s to keep trying a database that could be reached and cannot any more (a "
        f"restart, a failover) before {who} stops (default 300)",
    )


def _patience(args: argparse.Namespace) -> dict[str, Any]:
    """``--storage-patience`` as a keyword argument, where it was given."""
    return {} if args.storage_patience is None else {"storage_patience_s": args.storage_patience}


def _worker(args: argparse.Namespace) -> int:
    import os

    from .effects import load_plugin
    from .identify._jobs import STORAGE_VARIABLE
    from .identify._worker import work

    for module in args.plugin:
        load_plugin(module)
    storage = args.storage or os.environ.get(STORAGE_VARIABLE)
    if not storage:
        raise InputDataError(
            f"surrogate worker needs --storage URL (or ${STORAGE_VARIABLE}): the planner's storage"
        )
    result = work(
        args.study,
        storage=storage,
        jobs=args.jobs,
        heartbeat_s=args.heartbeat,
        idle_timeout_s=args.idle_timeout,
        **_patience(args),
        progress=not args.json,
        max_runs=args.max_runs,
        queue=args.queue,
    )
    if args.json:
        _print_json(result.to_json())
    else:
        print(
            f"{result.runs} runs finished ({result.ok} ok, {result.failed} failed, "
            f"{result.solved} solved, the rest from the cache) in {result.study!r}"
        )
    if result.interrupted in ("SIGTERM", "SIGINT"):
        return 128 + int(getattr(signal, result.interrupted))
    return 0


# surrogate status ----------------------------------------------------------------------


def _add_status(commands: _Subparsers) -> argparse.ArgumentParser:
    state = commands.add_parser(
        "status", help="a study's queued and running runs and their scheduler jobs"
    )
    state.add_argument("study", type=Path, help="study file")
    _add_storage(state, help="Optuna storage URL (default: the study's)")
    _add_json(state)
    return state


def _status(args: argparse.Namespace) -> int:
    from .identify._status import status

    result = status(args.study, storage=args.storage)
    if args.json:
        _print_json(result.to_json())
        return 0
    print(f"study {result.study!r} in {result.storage}")
    for name, n in result.queues.items():
        print(
            f"{name}: {n['queued']} queued, {n['running']} running, {n['finished']} finished "
            f"({n['ok']} ok, {n['failed']} failed), {n['given_back']} given back and queued again"
        )
    if result.jobs:
        print("jobs" + ("" if result.live else " (as last recorded; the scheduler is not here)"))
    for job in result.jobs:
        why = f" ({job['reason']})" if job["reason"] else ""
        code = "" if job["exit_code"] is None else f", exit code {job['exit_code']}"
        run = "" if job["run"] is None else f", runs trial {job['run']}"
        print(f"  {job['job_id']:>8} {job['state']}{why}{code}{run}  [{job['queue']}]")
    return 0


# The command line ----------------------------------------------------------------------

_COMMANDS: tuple[tuple[Callable[[_Subparsers], argparse.ArgumentParser], _Handler], ...] = (
    (_add_simulate, _simulate),
    (_add_doe, _doe),
    (_add_fit, _fit),
    (_add_predict, _predict),
    (_add_run, _run),
    (_add_calibrate, _calibrate),
    (_add_compare, _compare),
    (_add_export, _export),
    (_add_report, _report),
    (_add_diagnose, _diagnose),
    (_add_next_test, _next_test),
    (_add_dashboard, _dashboard),
    (_add_worker, _worker),
    (_add_status, _status),
)
"""(declare the arguments, handle the command) per command, in the order of ``--help``."""


def _package_version() -> str:
    """The installed distribution's version, else (a source tree not installed)
    ``surrogate.__version__``."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("webbing-surrogate")
    except PackageNotFoundError:
        from . import __version__

        return __version__


def _build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog="surrogate",
        description="Identify the coating of seat-belt webbing from 2-point bending tests.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_package_version()}")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)
    for add, handler in _COMMANDS:
        add(commands).set_defaults(handler=handler)
    return parser


def _ctrl_c_again(unraisable: Any) -> None:
    """``sys.unraisablehook``: a Ctrl-C that Python swallowed is sent again 10 ms later.
    A KeyboardInterrupt raised in a weakref callback, a ``__del__`` or a ctypes callback
    (the garbage collector's; numba's compiler's) is printed as "Exception ignored" and
    dropped, and the command ran on to its end with exit 0 (seen: 1 in 12 Ctrl-Cs 0.6-1 s
    into ``surrogate run``). Anything else goes to the hook that was there."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        import os
        import threading

        threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGINT)).start()
        return
    _UNRAISABLE_HOOK[0](unraisable)


_UNRAISABLE_HOOK = [sys.unraisablehook]


def _interrupted_in_native_code(error: SystemError) -> bool:
    """A Ctrl-C that reached a compiled function (numba's dispatcher) as it returned:
    "returned a result with an exception set", the KeyboardInterrupt its cause."""
    return isinstance(error.__cause__ or error.__context__, KeyboardInterrupt)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``surrogate`` command; returns the exit code."""
    parser = _build_parser()
    args = parser.parse_args(argv)
    show_progress()
    drop_ctrl_c_echoes()
    sys.unraisablehook = _ctrl_c_again
    try:
        with _data_warnings_in_one_line():
            return int(args.handler(args))
    except InputDataError as error:
        _fail(f"error: {error}", EXIT_USAGE)
    except Interrupted as error:  # 143 or 130, as a shell reports a process the signal killed
        _stopped(str(error), 128 + int(getattr(signal, error.signal_name)), argv)
    except KeyboardInterrupt:
        _stopped("interrupted (Ctrl-C)", 128 + int(signal.SIGINT), argv)
    except SystemError as error:
        if not _interrupted_in_native_code(error):
            raise
        _stopped("interrupted (Ctrl-C)", 128 + int(signal.SIGINT), argv)
    except SolverError as error:
        _fail(f"solver error: {error}", EXIT_SOLVER)
    except IsADirectoryError as error:
        folder = error.filename2 or error.filename or error  # os.replace: the target's
        _fail(f"error: {folder} is a folder; name a file in it", EXIT_USAGE)
    except OSError as error:
        _fail(f"error: {error.strerror or error}: {error.filename}", EXIT_USAGE)
    except Exception as error:
        from .storage._storage import storage_error_message

        message = storage_error_message(error)
        if message is None:
            raise
        _fail(f"error: {message}", EXIT_USAGE)
    return 0


@contextlib.contextmanager
def _data_warnings_in_one_line() -> Iterator[None]:
    """An :class:`InputDataWarning` as ``surrogate: warning: …`` on stderr (Python's
    default adds the source line); other warnings as Python shows them."""
    shown = warnings.showwarning

    def show(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
        if issubclass(category, InputDataWarning):
            print(f"surrogate: warning: {message}", file=sys.stderr)
        else:
            shown(message, category, *args, **kwargs)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def _stopped(message: str, code: int, argv: Sequence[str] | None) -> NoReturn:
    """:func:`_fail` for a command a signal stopped. Where the command is the process's own
    (``argv`` None: the ``surrogate`` command, ``python -m surrogate``), SIGINT is ignored from
    here on: the process has said that it stopped and how, and a second Ctrl-C — the
    user's, or one :func:`_ctrl_c_again` sends again — must not end it on its way out with
    another status (seen once in a suite under load: the line printed, then the process
    killed by SIGINT, −2 where 130 was due; not reproduced). A caller's own ``main(argv)``
    keeps its handler."""
    while argv is None:
        try:  # (a Ctrl-C already pending is handled first: it raises here, and is dropped)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            break
        except KeyboardInterrupt:
            continue
    _fail(message, code)


def _fail(message: str, code: int) -> NoReturn:
    print(f"surrogate: {message}", file=sys.stderr)
    raise SystemExit(code)
