"""Quasi-static 2-point bending of an inextensible strip: a discrete elastic rod.

Notations
---------
Coordinates (x, z) [mm]: the clamp pivot (rotation axis, on the mid-plane at the
clamp edge) is the origin, the undeformed strip lies along +x, the probe is
above it.

N          number of straight segments of the mid-line.
h          (N,) segment lengths [mm]; the mid-line is inextensible.
psi        (N,) segment angles [rad]; the unknowns.
r          (N+1, 2) node positions, ``r[0] = 0``, ``r[i+1] = r[i] + h[i]·e(psi[i])``.
theta      clamp rotation [rad]; the clamp imposes the tangent ``theta`` at s = 0.
kappa      (N,) curvature at nodes 0..N-1 (node 0 is the clamp edge, where the
           clamp's tangent meets segment 0); Voronoi lengths ``ell``.
c          probe centre ``(l, rho)`` with ``rho`` the contact radius: the
           mid-line keeps the distance ``rho = probe_radius + t/2`` from ``c``.
lam        normal contact force [N] (Lagrange multiplier of ``gap = 0``).
J          (2, N) derivative of the contact point with respect to ``psi``.

Each load step solves the KKT system of the incremental problem by Newton's
method: bending moments from the section law, the dead tension at the free
end, the self-weight (a dead load ``q`` per unit length along -z), frictional
contact with the probe (regularised Coulomb law on the slip of the material
point in contact), and the gap equation.  The Jacobian is exact (checked
against finite differences in the tests).

Contact is an active set: under self-weight the strip sags away from the probe
and touches it only after some rotation, and it may lift off again; a step
whose contact force comes out negative is solved again without contact, and a
free step that penetrates the probe again with it.

A compliant clamp (rotational spring ``k_c`` [N·mm/rad] between the fixture
and the strip) is a zero-length first segment whose angle is the strip's
tangent at the clamp edge: node 0 carries the spring moment
``k_c·(psi[0] − theta)`` instead of the section law.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .._errors import SolverError
from ._coating import CoatingSection, SectionState

__all__ = ["RodSolution", "default_mesh", "solve_cantilever", "solve_rod", "uniform_mesh"]

_HYSTERESIS = 0.05  # of a segment length, see _find_contact
_STICK_STIFFNESS_FACTOR = 1e5  # tangential penalty of sticking, in units of EI/l³
_MAX_NEWTON = 40
_MAX_BACKTRACKS = 6
_MAX_INITIAL_STIFFNESS = 1500
_REFACTOR_EVERY = 25
_STALL_ITERATIONS = 6
_UNLOADING_FLOOR = 0.05  # of the elastic section stiffness, see _newton
_MAX_BISECTIONS = 8


@dataclass(frozen=True)
class RodSolution:
    """History of a bending run, one entry per requested angle.

    Forces are those the probe receives, for the full specimen width [N].
    """

    angle_deg: np.ndarray
    force_n: np.ndarray
    force_perp_n: np.ndarray
    normal_force_n: np.ndarray
    contact_arc_mm: np.ndarray
    clamp_moment_nmm: np.ndarray
    max_plastic_curvature_per_mm: np.ndarray
    segment_lengths_mm: np.ndarray


def uniform_mesh(length_mm: float, element_size_mm: float) -> np.ndarray:
    """Segment lengths of a uniform mesh with elements no longer than the size."""
    n = max(1, int(np.ceil(length_mm / element_size_mm - 1e-9)))
    return np.full(n, length_mm / n)


def default_mesh(
    length_mm: float, bending_length_mm: float, *, fine_fraction: float = 1.0 / 25.0
) -> np.ndarray:
    """Fine segments over the loaded zone, geometrically coarser in the tail.

    The loaded zone (clamp to the farthest contact point, about 1.5·l at 90°)
    gets segments of ``fine_fraction·l``; beyond ``1.8·l`` the tail, which only
    carries the end load, grows by 25 % per segment up to 10× the fine size.
    """
    fine = fine_fraction * bending_length_mm
    fine_end = min(length_mm, 1.8 * bending_length_mm)
    lengths = list(uniform_mesh(fine_end, fine))
    s, size = fine_end, fine
    while s < length_mm - 1e-9:
        size = min(size * 1.25, 10.0 * fine)
        step = min(size, length_mm - s)
        if length_mm - s - step < 0.3 * size:  # avoid a sliver at the end
            step = length_mm - s
        lengths.append(step)
        s += step
    return np.asarray(lengths)


@dataclass
class _Contact:
    """Closest point of the mid-line to the probe centre and its derivatives."""

    segment: int  # contact segment k (segment case) or first segment after the vertex
    on_vertex: bool
    upstream: int  # segments wholly between the clamp and the contact point
    u: float  # position of the contact point along segment k [mm]
    point: np.ndarray  # (2,)
    distance: float  # signed distance from the mid-line to the probe centre
    normal: np.ndarray  # (2,) unit vector from the contact point to the probe centre
    tangent: np.ndarray  # (2,) normal rotated by -90°: along the strip, away from the clamp
    jac: np.ndarray  # (2, N) d(point)/d(psi) at fixed u
    dbeta: np.ndarray  # (N,) derivative of the normal's angle


def _directions(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents ``e`` and normals ``n`` (``e`` turned by +90°), shape (N, 2)."""
    cos, sin = np.cos(psi), np.sin(psi)
    e = np.empty((psi.size, 2))
    n = np.empty((psi.size, 2))
    e[:, 0], e[:, 1] = cos, sin
    n[:, 0], n[:, 1] = -sin, cos
    return e, n


def _nodes(h: np.ndarray, e: np.ndarray) -> np.ndarray:
    nodes = np.zeros((h.size + 1, 2))
    np.cumsum(h[:, None] * e, axis=0, out=nodes[1:])
    return nodes


def _find_contact(
    h: np.ndarray,
    e: np.ndarray,
    n: np.ndarray,
    nodes: np.ndarray,
    centre: np.ndarray,
    preferred: int | None = None,
) -> _Contact:
    rel = centre[None, :] - nodes[:-1]
    u_raw = np.einsum("ij,ij->i", e, rel)
    u = np.clip(u_raw, 0.0, h)
    closest = nodes[:-1] + u[:, None] * e
    distance = np.sqrt(np.sum((centre[None, :] - closest) ** 2, axis=1))
    k = int(np.argmin(distance))
    if (
        preferred is not None
        and 0.0 < u_raw[preferred] < h[preferred]
        and distance[preferred] - distance[k] < _HYSTERESIS * h[preferred]
    ):
        # Where the strip is concave towards the probe, the probe centre
        # projects onto two neighbouring segments and the nearer one flips
        # between Newton iterates; keep the segment in use until the
        # projection leaves it (the other segment's overlap is ~rho·kink²).
        k = preferred
    N = h.size
    jac = np.zeros((2, N))
    if 0.0 < u_raw[k] < h[k]:
        # Segment case: the signed distance stays meaningful for a Newton
        # iterate that over-shoots the probe centre.
        jac[:, :k] = (h[:k, None] * n[:k]).T
        jac[:, k] = u_raw[k] * n[k]
        dbeta = np.zeros(N)
        dbeta[k] = 1.0
        return _Contact(
            k, False, k, float(u_raw[k]), closest[k], float(n[k] @ rel[k]), n[k], e[k], jac, dbeta
        )
    v = k + 1 if u_raw[k] >= h[k] else k  # the vertex is node v
    point = nodes[v]
    diff = centre - point
    distance = float(np.hypot(diff[0], diff[1]))
    normal = diff / distance
    tangent = np.array([normal[1], -normal[0]])
    jac[:, :v] = (h[:v, None] * n[:v]).T
    dbeta = (tangent @ jac) / distance
    return _Contact(min(v, N - 1), True, v, 0.0, point, distance, normal, tangent, jac, dbeta)


@dataclass
class _Evaluation:
    """Residual of the KKT system at one iterate, with what its Jacobian needs."""

    psi: np.ndarray
    lam: float
    residual: np.ndarray  # (N+1,): moments [N·mm] then the gap [mm]
    state: SectionState  # after the return mapping
    moment: np.ndarray  # (N,) total moment at nodes 0..N-1 [N·mm]
    stiff: np.ndarray  # (N,) tangent dM/dkappa / ell [N·mm]
    kappa: np.ndarray  # (N,) curvature at the nodes [1/mm]
    e: np.ndarray
    contact: _Contact | None  # None without a probe
    friction_n: float  # friction force on the strip along the contact tangent [N]
    sticking: bool
    slip_vec: np.ndarray
    active: bool = True  # the contact force acts (False: the strip is off the probe)
    gap: float = 0.0  # of a free strip: distance from the probe surface [mm], < 0 penetrates


@dataclass(frozen=True)
class _Configuration:
    """A converged configuration, the reference for the next step's slip."""

    psi: np.ndarray
    lam: float
    state: SectionState
    friction_n: float
    nodes: np.ndarray
    e: np.ndarray


class _Problem:
    """Everything fixed during a run: geometry, loads, the section law."""

    def __init__(
        self,
        section: CoatingSection,
        h: np.ndarray,
        *,
        width_mm: float,
        bending_length_mm: float,
        contact_radius_mm: float | None,
        friction: float,
        tension_n: float,
        line_load_n_mm: float = 0.0,
        clamp_stiffness_nmm: float | None = None,
    ) -> None:
        self.section = section
        self.segment_lengths_mm = h  # the mesh as given
        self.bending_length = bending_length_mm
        if clamp_stiffness_nmm is not None:
            h = np.concatenate([[0.0], h])  # the zero-length clamp segment
        self.h = h
        self.spring = clamp_stiffness_nmm
        self.line_load = line_load_n_mm
        # Weight moment arm of each segment: the length it carries downstream.
        self.carried = np.cumsum(h[::-1])[::-1] - 0.5 * h
        self.active = True  # the contact is in the active set
        self.N = h.size
        self.width = width_mm
        # No probe (None) is for verification against the cantilever table.
        self.has_probe = contact_radius_mm is not None
        self.rho = contact_radius_mm if contact_radius_mm is not None else 0.0
        self.centre = np.array([bending_length_mm, self.rho])
        self.mu = friction
        self.tension = tension_n
        ell = np.empty(self.N)
        ell[0] = h[0] / 2.0
        ell[1:] = 0.5 * (h[:-1] + h[1:])
        if self.spring is not None:
            ell[0] = 1.0  # placeholder: node 0 is the spring, not a section
        self.ell = ell
        self.stiffness_scale = section.stiffness_nmm * width_mm / bending_length_mm
        self.elastic_stiff = section.stiffness_nmm * width_mm / self.ell
        if self.spring is not None:
            self.elastic_stiff[0] = self.spring
        self.stick_stiffness = _STICK_STIFFNESS_FACTOR * self.stiffness_scale / bending_length_mm**2
        self._diag = np.arange(self.N)

    def configuration(
        self, psi: np.ndarray, lam: float, state: SectionState, friction_n: float
    ) -> _Configuration:
        e, _ = _directions(psi)
        return _Configuration(psi, lam, state, friction_n, _nodes(self.h, e), e)

    def evaluate(
        self,
        psi: np.ndarray,
        lam: float,
        theta: float,
        previous: _Configuration,
        preferred: int | None = None,
    ) -> _Evaluation:
        """Residual of equilibrium and of the gap at ``(psi, lam)``."""
        N, h = self.N, self.h
        kappa, moment, stiff, state = self._bending(psi, theta, previous.state)
        residual = np.empty(N + 1)
        residual[:N] = moment
        residual[: N - 1] -= moment[1:]
        e, n = _directions(psi)
        if self.tension:
            residual[:N] += self.tension * h * e[:, 1]
        if self.line_load:
            residual[:N] += self.line_load * h * self.carried * e[:, 0]
        contact = (
            _find_contact(h, e, n, _nodes(h, e), self.centre, preferred) if self.has_probe else None
        )
        active = contact is not None and self.active
        friction, sticking, slip_vec = 0.0, False, np.zeros(2)
        if contact is None or not active:
            residual[N] = lam  # no probe, or the strip is off it: no contact force
        else:
            residual[:N] += lam * (contact.normal @ contact.jac)
            residual[N] = contact.distance - self.rho
        if active and self.mu:
            assert contact is not None
            friction, sticking, slip_vec = self._friction(contact, lam, previous)
            residual[:N] -= friction * (contact.tangent @ contact.jac)
        return _Evaluation(
            psi,
            lam,
            residual,
            state,
            moment,
            stiff,
            kappa,
            e,
            contact,
            friction,
            sticking,
            slip_vec,
            active=active,
            gap=0.0 if contact is None else contact.distance - self.rho,
        )

    def _bending(
        self, psi: np.ndarray, theta: float, previous: SectionState
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, SectionState]:
        """Curvatures ``kappa`` at the nodes, the moments and tangent stiffnesses of
        the section law (full width), and the new section state; node 0 carries
        the clamp spring instead when there is one."""
        kappa = np.empty(self.N)
        kappa[0] = psi[0] - theta
        kappa[1:] = psi[1:] - psi[:-1]
        kappa /= self.ell
        if self.spring is not None:
            rotation = kappa[0]
            kappa[0] = 0.0  # the spring node keeps an unused, unloaded section
        m_unit, c_unit, state = self.section.respond(kappa, previous)
        moment = m_unit * self.width
        stiff = c_unit * self.width / self.ell
        if self.spring is not None:
            moment[0] = self.spring * rotation
            stiff[0] = self.spring
        return kappa, moment, stiff, state

    def _friction(
        self, contact: _Contact, lam: float, previous: _Configuration
    ) -> tuple[float, bool, np.ndarray]:
        """The friction force, whether it sticks, and the slip of the material point
        in contact since ``previous``."""
        if contact.on_vertex:
            before = previous.nodes[contact.upstream]
        else:
            k = contact.segment
            before = previous.nodes[k] + contact.u * previous.e[k]
        slip_vec = contact.point - before
        # Coulomb's law by return mapping: stick elastically, else slide.
        slip = float(contact.tangent @ slip_vec)
        trial = previous.friction_n - self.stick_stiffness * slip
        limit = self.mu * max(lam, 0.0)
        sticking = abs(trial) <= limit
        friction = trial if sticking else float(np.copysign(limit, trial))
        return friction, sticking, slip_vec

    def jacobian(self, ev: _Evaluation, stiff: np.ndarray | None = None) -> np.ndarray:
        """Exact derivative of ``ev.residual`` with respect to ``(psi, lam)``.

        ``stiff`` replaces the section tangents (see :func:`_newton`).
        """
        N, h, idx = self.N, self.h, self._diag
        contact, lam = ev.contact, ev.lam
        stiff = ev.stiff if stiff is None else stiff
        jacobian = np.zeros((N + 1, N + 1))
        diag = stiff.copy()
        diag[:-1] += stiff[1:]
        if self.tension:
            diag += self.tension * h * ev.e[:, 0]
        if self.line_load:
            diag -= self.line_load * h * self.carried * ev.e[:, 1]
        jacobian[idx, idx] = diag
        jacobian[idx[:-1], idx[1:]] = -stiff[1:]
        jacobian[idx[1:], idx[:-1]] = -stiff[1:]
        if contact is None or not ev.active:
            jacobian[N, N] = 1.0
            return jacobian
        k, up = contact.segment, contact.upstream
        d_hat, tau, dbeta = contact.normal, contact.tangent, contact.dbeta
        normal_j = d_hat @ contact.jac  # = -d(gap)/d(psi)
        tangent_j = tau @ contact.jac
        e_up = ev.e[:up]
        # Hessian of the gap, times -lam.
        hess = np.outer(tangent_j, dbeta)
        hess[idx[:up], idx[:up]] += h[:up] * (e_up @ d_hat)
        if not contact.on_vertex:
            hess[k, :] += tangent_j
            hess[k, k] -= contact.distance
        block = jacobian[:N, :N]
        block -= lam * hess
        jacobian[:N, N] = normal_j
        jacobian[N, :N] = -normal_j
        if self.mu:
            # d(tau·J)/d(psi), times the friction force
            turn = np.outer(normal_j, dbeta)
            turn[idx[:up], idx[:up]] -= h[:up] * (e_up @ tau)
            if not contact.on_vertex:
                turn[k, k] -= contact.u
            block -= ev.friction_n * turn
            if ev.sticking:
                dslip = tangent_j + dbeta * float(d_hat @ ev.slip_vec)
                block += self.stick_stiffness * np.outer(tangent_j, dslip)
            elif lam > 0.0:
                jacobian[:N, N] -= self.mu * np.sign(ev.friction_n) * tangent_j
        return jacobian

    def residual_scales(self) -> tuple[np.ndarray, np.ndarray]:
        """Weights that make the residual dimensionless (moments by D·b/l, the
        gap by l) and the convergence tolerance of each scaled entry."""
        weights = np.full(self.N + 1, 1.0 / self.stiffness_scale)
        weights[-1] = 1.0 / self.centre[0]
        tolerance = np.full(self.N + 1, 1e-9)
        tolerance[-1] = 1e-10
        return weights, tolerance

    def forces(self, ev: _Evaluation) -> tuple[float, float]:
        """Resultant and perpendicular force on the probe [N]."""
        contact = ev.contact
        if contact is None or not ev.active:
            return 0.0, 0.0
        on_probe = ev.lam * contact.normal - ev.friction_n * contact.tangent
        return float(np.hypot(on_probe[0], on_probe[1])), float(on_probe[1])


def _newton(
    problem: _Problem,
    psi: np.ndarray,
    lam: float,
    theta: float,
    previous: _Configuration,
) -> _Evaluation | None:
    """Solve one load step; ``None`` when Newton does not converge.

    The moment–curvature law is only piecewise smooth (each coat fibre kinks
    at its yield point). Where a node's tangent changed between the last two
    iterates, its secant slope replaces the tangent, and a backtracking line
    search on the scaled residual guards the step: together they stop the
    cycling of plain Newton when a fibre sits at its yield point.
    """
    weights, tolerance = problem.residual_scales()
    preferred = None

    def attempt(psi: np.ndarray, lam: float) -> tuple[_Evaluation, float]:
        nonlocal preferred
        ev = problem.evaluate(psi, lam, theta, previous, preferred)
        if ev.contact is not None and not ev.contact.on_vertex:
            preferred = ev.contact.segment
        merit = float(np.sum((ev.residual * weights) ** 2))
        return ev, merit if np.isfinite(merit) else np.inf

    ev, merit = attempt(psi, lam)
    stiff = None
    best, since_best = merit, 0
    for _ in range(_MAX_NEWTON):
        if not np.isfinite(merit):
            return None
        scaled = np.abs(ev.residual * weights)
        if np.all(scaled < tolerance):
            return ev
        if since_best >= _STALL_ITERATIONS:
            return None  # stalled: leave it to _initial_stiffness
        try:
            delta = np.linalg.solve(problem.jacobian(ev, stiff), -ev.residual)
        except np.linalg.LinAlgError:
            return None
        # Limit the rotation update: the contact search is only valid nearby.
        step = min(1.0, 0.2 / max(float(np.max(np.abs(delta[:-1]))), 1e-300))
        full_step = step
        for _ in range(_MAX_BACKTRACKS):
            trial, trial_merit = attempt(ev.psi + step * delta[:-1], ev.lam + step * delta[-1])
            if trial_merit < (1.0 - 1e-4 * step) * merit:
                break
            step *= 0.5
        stiff = _secant_stiffness(problem, ev, trial)
        if step < full_step:
            # A kink stopped the full step: let fully plastic nodes see that
            # they may unload (their tangent is zero on the loading side).
            stiff = np.maximum(stiff, _UNLOADING_FLOOR * problem.elastic_stiff)
        ev, merit = trial, trial_merit
        if merit < 0.5 * best:
            best, since_best = merit, 0
        else:
            since_best += 1
    return None


def _initial_stiffness(
    problem: _Problem,
    psi: np.ndarray,
    lam: float,
    theta: float,
    previous: _Configuration,
) -> _Evaluation | None:
    """Fallback for :func:`_newton`: iterate with the elastic section stiffness.

    Where a plastic hinge passes from one node to the next, two neighbouring
    nodes sit at the plastic moment with zero tangent and the contact makes
    the segment between them geometrically soft: Newton stalls, and only the
    unloading of one node resolves it. Iterating with the elastic stiffness
    (the classic initial-stiffness method) lets that node unload; it converges
    linearly, in a few hundred cheap iterations, so it is kept for this case.
    """
    weights, tolerance = problem.residual_scales()
    ev = problem.evaluate(psi, lam, theta, previous)
    factors = None
    for iteration in range(_MAX_INITIAL_STIFFNESS):
        scaled = np.abs(ev.residual * weights)
        if not np.all(np.isfinite(scaled)):
            return None
        if np.all(scaled < tolerance):
            return ev
        if iteration % _REFACTOR_EVERY == 0:  # the contact geometry drifts slowly
            try:
                factors = scipy.linalg.lu_factor(
                    problem.jacobian(ev, problem.elastic_stiff), check_finite=False
                )
            except (np.linalg.LinAlgError, ValueError):
                return None
        delta = scipy.linalg.lu_solve(factors, -ev.residual, check_finite=False)
        preferred = None if ev.contact is None or ev.contact.on_vertex else ev.contact.segment
        ev = problem.evaluate(ev.psi + delta[:-1], ev.lam + delta[-1], theta, previous, preferred)
    return None


def _secant_stiffness(problem: _Problem, old: _Evaluation, new: _Evaluation) -> np.ndarray:
    """Section tangents of ``new``, with secants where the tangent switched."""
    switched = (new.stiff != old.stiff) & (np.abs(new.kappa - old.kappa) > 1e-14)
    if not np.any(switched):
        return new.stiff
    stiff = new.stiff.copy()
    secant = (new.moment - old.moment)[switched] / (new.kappa - old.kappa)[switched]
    stiff[switched] = secant / problem.ell[switched]
    return stiff


def _record(problem: _Problem, ev: _Evaluation) -> tuple[float, ...]:
    force, perp = problem.forces(ev)
    contact = ev.contact
    assert contact is not None  # a run with a probe always has a contact
    arc = float(np.sum(problem.h[: contact.upstream]) + contact.u)
    kappa_p = problem.section.plastic_curvature(ev.state)
    # The probe bends the strip clockwise (negative curvature): report the
    # clamp moment with the sign of the lifting rotation.
    return (force, perp, ev.lam, arc, -float(ev.moment[0]), float(np.max(np.abs(kappa_p))))


def solve_rod(
    section: CoatingSection,
    angles_deg: np.ndarray,
    *,
    segment_lengths_mm: np.ndarray,
    width_mm: float,
    bending_length_mm: float,
    contact_radius_mm: float,
    friction: float,
    tension_n: float = 0.0,
    line_load_n_mm: float = 0.0,
    clamp_stiffness_nmm: float | None = None,
) -> RodSolution:
    """Rotate the clamp through ``angles_deg`` (increasing, from 0) and record.

    Parameters
    ----------
    section : CoatingSection
        Moment–curvature law of the strip.
    angles_deg : array_like, shape (n_angles,)
        Clamp rotations at which to record, increasing, ≥ 0 [deg].
    segment_lengths_mm : array_like, shape (N,)
        The mesh (see :func:`default_mesh`, :func:`uniform_mesh`).
    width_mm, bending_length_mm : float
        Specimen width ``b`` and horizontal clamp–probe distance ``l``.
    contact_radius_mm : float
        Distance kept between the mid-line and the probe centre
        (probe radius + t/2); > 0.
    friction : float
        Coulomb coefficient at the probe.
    tension_n : float
        Dead load at the free end along +x [N].
    line_load_n_mm : float
        Self-weight per unit length of the strip (full width), along -z
        [N/mm]; the strip sags away from the probe before the rotation starts.
    clamp_stiffness_nmm : float, optional
        Rotational stiffness of the clamp (full width) [N·mm/rad]; ``None``
        is a rigid clamp.

    Raises
    ------
    SolverError
        When a step does not converge even after bisection, the strip slides
        off the probe, or it loses contact; the message names the angle.
    """
    problem = _Problem(
        section,
        np.asarray(segment_lengths_mm, dtype=float),
        width_mm=width_mm,
        bending_length_mm=bending_length_mm,
        contact_radius_mm=contact_radius_mm,
        friction=friction,
        tension_n=tension_n,
        line_load_n_mm=line_load_n_mm,
        clamp_stiffness_nmm=clamp_stiffness_nmm,
    )
    return _history(problem, np.asarray(angles_deg, dtype=float))


def _history(problem: _Problem, angles_deg: np.ndarray) -> RodSolution:
    """March ``problem`` through ``angles_deg`` and record each converged state."""
    at_rest = (0.0, 0.0, 0.0, problem.bending_length, 0.0, 0.0)
    history = [
        at_rest if ev is None else _record(problem, ev)
        for ev, _ in _march(problem, np.radians(angles_deg))
    ]
    columns = np.array(history).T
    return RodSolution(
        angle_deg=angles_deg,
        force_n=columns[0],
        force_perp_n=columns[1],
        normal_force_n=columns[2],
        contact_arc_mm=columns[3],
        clamp_moment_nmm=columns[4],
        max_plastic_curvature_per_mm=columns[5],
        segment_lengths_mm=problem.segment_lengths_mm,
    )


def _march(
    problem: _Problem, angles_rad: np.ndarray
) -> Iterator[tuple[_Evaluation | None, _Configuration]]:
    """Rotate the clamp through ``angles_rad``; yield each converged state.

    Each interval is one load step, bisected when Newton fails; the
    predictor extrapolates the last step's rates. ``None`` stands for the
    unloaded state at 0°.
    """
    n = problem.N
    current = problem.configuration(np.zeros(n), 0.0, problem.section.initial_state(n), 0.0)
    if problem.line_load:
        current = _sag(problem, current)
    rates = (np.zeros(n), 0.0)  # d(psi)/d(theta), d(lam)/d(theta) of the last step
    theta_done = 0.0
    last: _Evaluation | None = None
    for target in angles_rad:
        span, substeps = target - theta_done, 1
        while theta_done < target - 1e-12:
            theta = min(target, theta_done + span / substeps)
            dtheta = theta - theta_done
            guess_psi = current.psi + rates[0] * dtheta
            guess_lam = max(current.lam + rates[1] * dtheta, 0.0)
            ev = _step(problem, guess_psi, guess_lam, theta, current)
            if ev is None:
                substeps *= 2
                if substeps > 2**_MAX_BISECTIONS:
                    raise SolverError(
                        f"the bending solver did not converge at {np.degrees(theta):.2f}° "
                        f"(last converged {np.degrees(theta_done):.2f}°); "
                        "try another element_size_mm or check the coating values"
                    )
                continue
            _check_contact(ev, n, theta)
            rates = ((ev.psi - current.psi) / dtheta, (ev.lam - current.lam) / dtheta)
            current = problem.configuration(ev.psi, ev.lam, ev.state, ev.friction_n)
            theta_done = theta
            last = ev
        yield last, current


def _step(
    problem: _Problem,
    psi: np.ndarray,
    lam: float,
    theta: float,
    previous: _Configuration,
) -> _Evaluation | None:
    """One load step with the contact's active set; ``None`` when it fails.

    Only a strip under self-weight may leave the probe; without it a negative
    contact force is an error (see :func:`_check_contact`).
    """
    was_active = problem.active
    for _ in range(3):
        ev = _newton(problem, psi, lam, theta, previous)
        if ev is None:
            ev = _initial_stiffness(problem, psi, lam, theta, previous)
        if ev is None:
            break
        if problem.active and ev.lam < 0.0 and problem.line_load:
            problem.active, lam = False, 0.0
        elif not problem.active and ev.gap < 0.0:
            problem.active, lam = True, 0.0
        else:
            return ev
    problem.active = was_active
    return None


def _sag(problem: _Problem, rest: _Configuration) -> _Configuration:
    """Equilibrium at 0° under self-weight, off the probe (the weight ramped in)."""
    load = problem.line_load
    problem.active = False
    current = rest
    for fraction in np.linspace(0.0, 1.0, 5)[1:]:
        problem.line_load = fraction * load
        ev = _newton(problem, current.psi, 0.0, 0.0, current)
        if ev is None:
            raise SolverError("the strip did not find its equilibrium under its own weight at 0°")
        current = problem.configuration(ev.psi, 0.0, ev.state, 0.0)
    problem.line_load = load
    if ev.gap < 0.0:  # cannot happen with the probe above the strip; kept as a guard
        problem.active = True
    return current


def _check_contact(ev: _Evaluation, n_segments: int, theta: float) -> None:
    if ev.contact is None or not ev.active:
        return
    if ev.contact.upstream >= n_segments:
        raise SolverError(
            f"the strip slid off the probe at {np.degrees(theta):.2f}°; increase free_length_mm"
        )
    if ev.lam < 0.0:
        raise SolverError(
            f"the strip lost contact with the probe at {np.degrees(theta):.2f}° "
            f"(contact force {ev.lam:.3g} N < 0); check the end load"
        )


def solve_cantilever(
    section: CoatingSection,
    loads_n: np.ndarray,
    *,
    segment_lengths_mm: np.ndarray,
    width_mm: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Clamped strip under a dead tip load perpendicular to its clamped axis.

    A verification problem: the clamp holds the strip along +z (a 90° clamp
    rotation, no probe) and the end load acts along +x.

    Returns
    -------
    tip_mm : ndarray, shape (n_loads, 2)
        Tip deflection ``w`` (along the load) and axial shortening ``u``.
    tip_rotation_rad : ndarray, shape (n_loads,)
    """
    h = np.asarray(segment_lengths_mm, dtype=float)
    length = float(np.sum(h))
    problem = _Problem(
        section,
        h,
        width_mm=width_mm,
        bending_length_mm=length,
        contact_radius_mm=None,
        friction=0.0,
        tension_n=0.0,
    )
    theta = 0.5 * np.pi
    current = problem.configuration(np.full(h.size, theta), 0.0, section.initial_state(h.size), 0.0)
    tips, rotations = [], []
    load_done = 0.0
    for load in np.asarray(loads_n, dtype=float):
        for sub in np.linspace(load_done, load, 9)[1:]:
            problem.tension = float(sub)
            ev = _newton(problem, current.psi, 0.0, theta, current)
            if ev is None:
                raise SolverError(f"the cantilever did not converge at a load of {sub:g} N")
            current = problem.configuration(ev.psi, 0.0, ev.state, 0.0)
        load_done = load
        tip = current.nodes[-1]
        tips.append((tip[0], length - tip[1]))
        rotations.append(theta - current.psi[-1])
    return np.array(tips), np.array(rotations)
