"""The full-solver interface, its registry, and what every adapter shares.

A solver turns the plain-JSON inputs of :func:`surrogate.solvers.solver_inputs`
into a plain-JSON result: ``status`` (``ok``/``failed``), ``reason``, the
features ``f60_n``, ``theta_sat_deg``, ``saturated`` (always from
:func:`surrogate.physics.curve_features`) and the curve on whole degrees
(``angle_deg``, ``force_n``, ``force_perp_n``). :meth:`Solver.solve` makes a
failure a result, never an exception, so one bad point does not stop a batch;
:meth:`Solver.run` (what :func:`surrogate.simulate` calls) raises it instead.
What the solver models comes from :func:`surrogate.solvers.model_state`.

External solvers run in a working directory of their own (a temporary one,
removed afterwards unless the settings say ``keep_workdir``), are started
without a shell from an argument list, and are killed at their timeout.
"""

from __future__ import annotations

import functools
import os
import shlex
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .._errors import InputDataError, SolverError
from ..physics import curve_features

if TYPE_CHECKING:
    from ..effects import ModelState

__all__ = [
    "Solver",
    "available_solvers",
    "beyond_the_coat",
    "check_common_settings",
    "command_list",
    "curve_result",
    "failed_result",
    "get_solver",
    "guarded",
    "ok_result",
    "register_solver",
    "result_settings",
    "run_command",
    "run_identity",
    "work_directory",
]


class Solver:
    """Base class of full solvers.

    Subclasses set :attr:`name`, :attr:`version` (bump it when results change:
    it keys the result cache) and :attr:`settings_keys` (the keys allowed in
    ``inputs["solver_settings"]``), and implement :meth:`solve`.
    """

    name: ClassVar[str] = ""
    version: ClassVar[str] = ""
    settings_keys: ClassVar[tuple[str, ...]] = ()
    #: settings that say how to run, not what: not part of a run's identity (its hash),
    #: so the same run on another machine, checkout or timeout is the same run
    run_settings: ClassVar[tuple[str, ...]] = (
        "command",
        "timeout_s",
        "threads",
        "keep_workdir",
        "workdir_root",
    )

    def solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:  # pragma: no cover
        """One run; ``inputs`` as made by :func:`surrogate.solvers.solver_inputs`.

        A failed run is a result (``status`` ``failed`` with its ``reason``).
        """
        raise NotImplementedError

    def refuses(self, state: ModelState) -> str | None:
        """Why this solver cannot model ``state`` (an effect it has no physics for), or
        None; asked before a run, so a refused model is skipped with its reason."""
        return None

    def run(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        """One run whose failure raises: a SolverError naming the solver and the reason."""
        result = self.solve(inputs)
        if result["status"] != "ok":
            raise SolverError(f"{self.name}: {result['reason']}")
        return result

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        """Validated settings (unknown keys are refused); override to check values."""
        unknown = sorted(set(settings) - set(cls.settings_keys))
        if unknown:
            allowed = ", ".join(cls.settings_keys) or "none"
            raise InputDataError(
                f"[solver] {', '.join(unknown)} is not a setting of the {cls.name} solver; "
                f"allowed: {allowed}"
            )
        return dict(settings)


_REGISTRY: dict[str, type[Solver]] = {}


def result_settings(kind: str, settings: Mapping[str, Any] | None) -> dict[str, Any]:
    """The settings of ``kind`` that can change a run's result (its ``run_settings`` left out)."""
    run_only = _REGISTRY[kind].run_settings if kind in _REGISTRY else ()
    return {k: v for k, v in sorted((settings or {}).items()) if k not in run_only}


def run_identity(inputs: Mapping[str, Any]) -> dict[str, Any]:
    """What names a run (what :func:`surrogate.solvers.input_hash` hashes): its inputs
    with only the :func:`result_settings`; none at all when there are none."""
    identity = {k: v for k, v in inputs.items() if k != "solver_settings"}
    kept = result_settings(inputs.get("solver", "builtin"), inputs.get("solver_settings"))
    if kept:
        identity["solver_settings"] = kept
    return identity


def register_solver(cls: type[Solver]) -> type[Solver]:
    """Class decorator: make ``cls`` available as ``[solver] kind = cls.name``."""
    _REGISTRY[cls.name] = cls
    return cls


def available_solvers() -> tuple[str, ...]:
    """The registered kinds, in order of registration: the one list of solver kinds.

    ``builtin``, ``calculix`` and ``lsdyna`` register when :mod:`surrogate.solvers`
    is imported, which importing any of its modules does first.
    """
    return tuple(_REGISTRY)


def get_solver(kind: str) -> Solver:
    """The solver registered under ``kind`` (an InputDataError names the choices)."""
    if kind not in _REGISTRY:
        raise InputDataError(
            f"solver must be one of {', '.join(_REGISTRY)}, got {kind!r}; "
            "set [solver] kind or --solver"
        )
    return _REGISTRY[kind]()


# -- shared pieces ----------------------------------------------------------------------------
def failed_result(reason: str) -> dict[str, Any]:
    return {"status": "failed", "reason": reason}


def curve_result(
    angle_deg: np.ndarray, force_n: np.ndarray, force_perp_n: np.ndarray, max_angle_deg: float
) -> dict[str, Any]:
    """Resample a solver history to whole degrees and attach its features.

    Parameters
    ----------
    angle_deg : ndarray, shape (n,)
        Rotations at which the solver reported, increasing [deg].
    force_n, force_perp_n : ndarray, shape (n,)
        Resultant probe force and its component perpendicular to the
        undeformed strip, full specimen width [N].
    max_angle_deg : float
        The rig's range; a history that stops short of it is a failed run.
    """
    angle = np.asarray(angle_deg, dtype=float)
    end = np.floor(max_angle_deg)
    if angle.size < 2 or angle[-1] < end - 1e-3:
        reached = float(angle[-1]) if angle.size else 0.0
        return failed_result(f"the solver stopped at {reached:.2f}° of {end:g}°")
    angle[-1] = max(angle[-1], end)  # printed rotations carry ~7 digits
    if angle[0] > 0.0:  # the test has no preload: zero force at 0°
        angle = np.concatenate(([0.0], angle))
        force_n = np.concatenate(([0.0], force_n))
        force_perp_n = np.concatenate(([0.0], force_perp_n))
    grid = np.arange(0.0, end + 1.0)
    return ok_result(grid, np.interp(grid, angle, force_n), np.interp(grid, angle, force_perp_n))


def ok_result(
    angle_deg: np.ndarray, force_n: np.ndarray, force_perp_n: np.ndarray, **curves: np.ndarray
) -> dict[str, Any]:
    """The plain-JSON result of a successful run on whole degrees: the features (always
    from :func:`surrogate.physics.curve_features`), the curve and any further ``curves``."""
    features = curve_features(angle_deg, force_n)
    return {
        "status": "ok",
        "reason": "",
        "f60_n": features.f60_n,
        "theta_sat_deg": features.theta_sat_deg,
        "saturated": features.saturated,
        "angle_deg": np.asarray(angle_deg).tolist(),
        "force_n": np.asarray(force_n).tolist(),
        "force_perp_n": np.asarray(force_perp_n).tolist(),
        **{name: np.asarray(values).tolist() for name, values in curves.items()},
    }


@contextmanager
def work_directory(settings: Mapping[str, Any], *, prefix: str) -> Iterator[Path]:
    """A fresh working directory under ``settings["workdir_root"]`` (or the system
    temp dir), removed afterwards unless ``settings["keep_workdir"]`` is true."""
    root = settings.get("workdir_root")
    if root is not None:
        Path(root).mkdir(parents=True, exist_ok=True)
    path = Path(tempfile.mkdtemp(prefix=prefix, dir=root))
    try:
        yield path
    finally:
        if not settings.get("keep_workdir", False):
            shutil.rmtree(path, ignore_errors=True)


WATCH_EVERY_S = 1.0  # how often a run's ``stalled`` check is asked


class SolverStalled(SolverError):
    """A run stopped because its own progress said it would not finish
    (:func:`run_command`'s ``stalled``); the message says why."""


def run_command(
    args: Sequence[str],
    *,
    cwd: Path,
    timeout_s: float,
    env: Mapping[str, str] | None = None,
    stalled: Callable[[], str | None] | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run ``args`` (no shell) in ``cwd``; a timeout or a missing program is a SolverError.

    ``stalled`` (it must not raise), asked every ``WATCH_EVERY_S`` while the program
    runs, says why the run will not finish, or None; where it says why, the program is
    killed and :class:`SolverStalled` raised with that reason. A rule that reads the
    program's own progress gives the same verdict on every machine only if the caller
    asks it once more after the program ended (as the CalculiX adapter does).

    The solver dies with its caller: a timeout, a stall, SIGTERM or Ctrl-C kills its
    whole process group here (a wrapper script's children too), and on Linux a
    SIGKILLed caller takes it along too (``setpriv --pdeathsig``), so a killed worker
    leaves no solver running for nobody.
    """
    program = _program(args[0], cwd, env)
    if program is None:
        raise SolverError(f"{args[0]}: command not found; install it or set its path")
    command = [*_die_with_parent(), program, *args[1:]]
    with subprocess.Popen(
        command,
        cwd=cwd,
        env={**os.environ, **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",
        process_group=0,
    ) as process:
        try:
            return _watched(process, command, args[0], timeout_s, stalled)
        except BaseException:  # a timeout, a stall, Ctrl-C, SIGTERM: no orphan
            _kill(process)
            raise


def _watched(
    process: subprocess.Popen[str],
    command: list[str],
    name: str,
    timeout_s: float,
    stalled: Callable[[], str | None] | None,
) -> subprocess.CompletedProcess[str]:
    """Wait for ``process`` (see :func:`run_command`); ``communicate`` keeps what the
    program wrote across its own timeouts."""
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        if left <= 0.0:
            raise SolverError(f"{name} did not finish within {timeout_s:g} s (timeout_s)")
        try:
            stdout, stderr = process.communicate(
                timeout=left if stalled is None else min(left, WATCH_EVERY_S)
            )
        except subprocess.TimeoutExpired:
            reason = None if stalled is None else stalled()
            if reason is not None and process.poll() is None:
                raise SolverStalled(reason) from None
            continue
        return subprocess.CompletedProcess(command, process.returncode, stdout, stderr)


def _kill(process: subprocess.Popen[str]) -> None:
    """SIGKILL ``process``'s group (it leads its own) and reap it."""
    with suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signal.SIGKILL)
    process.wait()


def _program(name: str, cwd: Path, env: Mapping[str, str] | None) -> str | None:
    """The executable ``name`` runs: a path (relative to ``cwd``) or found on PATH."""
    if "/" in name or os.sep in name:
        path = Path(cwd, name)
        return str(path) if path.is_file() and os.access(path, os.X_OK) else None
    return shutil.which(name, path={**os.environ, **(env or {})}.get("PATH", os.defpath))


def _die_with_parent(caller: int | None = None) -> tuple[str, ...]:
    """``setpriv --pdeathsig KILL --`` where it works, else nothing; then a shell that
    runs the program only while its parent is still ``caller`` (this process by
    default): a caller killed between the fork and ``setpriv``'s ``prctl`` sets no death
    signal, and its orphan would run to the end (seen once in the suite: ``sleep 300``
    outlived its SIGKILLed caller). Built at each call: a forked worker is a caller of
    its own."""
    deathsig, shell = _deathsig(), shutil.which("sh")
    if not deathsig or shell is None:
        return ()
    alive = f'[ "$PPID" = {os.getpid() if caller is None else caller} ] || exit 137; exec "$@"'
    return (*deathsig, shell, "-c", alive, "sh")


@functools.cache
def _deathsig() -> tuple[str, ...]:
    """``setpriv --pdeathsig KILL --`` where it works (util-linux ≥ 2.33), else nothing."""
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return ()
    prefix = (setpriv, "--pdeathsig", "KILL", "--")
    try:
        works = subprocess.run([*prefix, "true"], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        works = False
    return prefix if works else ()


def beyond_the_coat(state: ModelState) -> str | None:
    """The effect whose physics ``state`` carries beyond the coat and the rig (a bare-webbing
    stiffness, self-weight, a compliant clamp), or None: what an adapter that passes only
    the coat to its solver cannot model."""
    if state.extra_stiffness_nmm:
        return "membrane_bending"
    if state.line_load_n_mm:
        return "gravity"
    if state.clamp_stiffness_nmm is not None:
        return "clamp_slip"
    return None


def guarded(solve: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """Call ``solve``; SolverError and InputDataError become a failed result."""
    try:
        return solve()
    except (SolverError, InputDataError) as error:
        return failed_result(str(error))


def check_common_settings(settings: Mapping[str, Any]) -> None:
    """Check the settings every external solver shares (``timeout_s``, ``command``,
    ``threads``, ``keep_workdir``); one line naming the key, the value and the rule."""
    timeout = settings.get("timeout_s", 1.0)
    if isinstance(timeout, bool) or not isinstance(timeout, int | float) or not timeout > 0:
        raise InputDataError(f"[solver] timeout_s must be a number of seconds > 0, got {timeout!r}")
    command = settings.get("command", "x")
    if not command or not (
        isinstance(command, str)
        or (isinstance(command, list) and all(isinstance(a, str) for a in command))
    ):
        raise InputDataError(
            f"[solver] command must be a program (with arguments) or a list of strings, "
            f"got {command!r}"
        )
    threads = settings.get("threads", 1)
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise InputDataError(f"[solver] threads must be a whole number ≥ 1, got {threads!r}")
    if not isinstance(settings.get("keep_workdir", False), bool):
        raise InputDataError(
            f"[solver] keep_workdir must be true or false, got {settings['keep_workdir']!r}"
        )


def command_list(command: str | Sequence[str]) -> list[str]:
    """An argument list: a list as it is, a string split as a shell would (never run by one)."""
    return [str(a) for a in command] if not isinstance(command, str) else shlex.split(command)
