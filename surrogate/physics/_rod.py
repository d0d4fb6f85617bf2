"""Quasi-static 2-point bending of an inextensible strip: a discrete elastic rod.

Notations
---------
Coordinates (x, z) [mm]: the clamp pivot (rotation axis, on the mid-plane at the
clamp edge) is the origin, the undeformed strip lies along +x, the probe is
above it.

N          number of straight segments of the mid-line.
h          (N,) segment lengths [mm]; the mid-line is inextensible.
psi        (N,) segment angles [rad]; the unknowns.
e, n       (N, 2) unit tangents ``(cos psi, sin psi)`` and normals ``(−sin psi, cos psi)``.
r          (N+1, 2) node positions, ``r[0] = 0``, ``r[i+1] = r[i] + h[i]·e(psi[i])``.
theta      clamp rotation [rad]; the clamp imposes the tangent ``theta`` at s = 0.
kappa      (N,) curvature at nodes 0..N-1 (node 0 is the clamp edge, where the
           clamp's tangent meets segment 0); Voronoi lengths ``ell``.
c          probe centre ``(l, rho)`` with ``rho`` the contact radius: the
           mid-line keeps the distance ``rho = probe_radius + t/2`` from ``c``.
lam        normal contact force [N] (Lagrange multiplier of ``gap = 0``).
J          (2, reach) derivative of the contact point with respect to
           ``psi[:reach]``, the angles that move it (``reach`` = k + 1 for a
           contact inside segment k, v for a contact at node v); ``a_n, a_t``
           its components along the contact normal and tangent.

Each load step solves the KKT system of the incremental problem by Newton's
method: bending moments from the section law, the dead tension at the free
end, the self-weight (a dead load ``q`` per unit length along -z), frictional
contact with the probe (regularised Coulomb law on the slip of the material
point in contact), and the gap equation.  The Jacobian is exact (checked
against finite differences in the tests).  It is tridiagonal but for the
contact, which couples ``psi[:reach]`` and ``lam`` densely; Newton's linear
system is solved by condensing the tridiagonal tail onto that head
(:class:`_Jacobian`).

Contact is an active set: under self-weight the strip sags away from the probe
and touches it only after some rotation, and it may lift off again; a step
whose contact force comes out negative is solved again without contact, and a
free step that penetrates the probe again with it.

A compliant clamp (rotational spring ``k_c`` [N·mm/rad] between the fixture
and the strip) is a zero-length first segment whose angle is the strip's
tangent at the clamp edge: node 0 carries the spring moment
``k_c·(psi[0] − theta)`` instead of the section law.

Speed: one curve is a few hundred iterates of about a hundred unknowns, where
numpy's overhead per call, not arithmetic, would set the pace. The residual,
the Jacobian and the linear solve of an iterate, and Newton's iterations of a
load step with their line search, are therefore compiled loops (numba:
``_evaluate_kernel``, ``_newton_direction``, ``_newton_kernel``; compiled at the
first call, some seconds, and cached on disk next to this file); the load
stepping, the active set and the initial-stiffness fallback stay in Python. A kernel writes an
iterate's node-wise quantities into the rows of one ``fields`` array and its
scalars into ``info`` (the ``_ROW_*`` and ``_INFO_*`` indices);
:class:`_Evaluation` reads them by name.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.linalg.lapack import dgetrf, dgetrs

from .._errors import SolverError
from ._coating import CoatingSection, Fibres, SectionState, return_mapping

__all__ = ["RodSolution", "default_mesh", "solve_cantilever", "solve_rod", "uniform_mesh"]

_HYSTERESIS = 0.05  # of a segment length, see _nearest_point
_STICK_STIFFNESS_FACTOR = 1e5  # tangential penalty of sticking, in units of EI/l³
_MAX_NEWTON = 40
_MAX_BACKTRACKS = 6
_MAX_INITIAL_STIFFNESS = 1500
_REFACTOR_EVERY = 25
_STALL_ITERATIONS = 6
_UNLOADING_FLOOR = 0.05  # of the elastic section stiffness, see _newton
_MAX_BISECTIONS = 8
_MOMENT_TOLERANCE = 1e-9  # of a moment residual scaled by D·b/l
_GAP_TOLERANCE = 1e-10  # of the gap scaled by l

# Rows of an iterate's ``fields`` array, shape (_N_ROWS, N+1); node-wise rows
# use the first N entries, the lever rows the first ``reach``.
_ROW_RESIDUAL = 0  # moments [N·mm] at nodes 0..N-1, then the gap row
_ROW_KAPPA = 1  # curvature [1/mm]
_ROW_MOMENT = 2  # moment, full width [N·mm]
_ROW_STIFF = 3  # section tangent dM/dkappa / ell [N·mm]
_ROW_COS = 4  # e_x of each segment
_ROW_SIN = 5  # e_z
_ROW_X = 6  # node positions [mm], N+1
_ROW_Z = 7
_ROW_NORMAL_J = 8  # a_n = normal·J [mm]
_ROW_TANGENT_J = 9  # a_t = tangent·J [mm]
_N_ROWS = 10

# Entries of an iterate's ``info`` array: the contact and the convergence.
_INFO_HAS_CONTACT = 0  # 1 with a probe (the nearest point exists), else 0
_INFO_SEGMENT = 1  # contact segment k, or the first segment after the vertex
_INFO_ON_VERTEX = 2
_INFO_UPSTREAM = 3  # segments wholly between the clamp and the contact point
_INFO_REACH = 4
_INFO_U = 5  # position of the contact point along segment k [mm]
_INFO_POINT_X = 6
_INFO_POINT_Z = 7
_INFO_DISTANCE = 8  # signed distance from the mid-line to the probe centre [mm]
_INFO_NORMAL_X = 9  # unit vector from the contact point to the probe centre
_INFO_NORMAL_Z = 10
_INFO_FRICTION = 11  # friction force on the strip along the contact tangent [N]
_INFO_STICKING = 12
_INFO_SLIP_X = 13  # slip of the material point in contact since the last step [mm]
_INFO_SLIP_Z = 14
_INFO_MERIT = 15  # squared norm of the scaled residual (inf if not finite)
_INFO_CONVERGED = 16  # every scaled residual entry is within its tolerance
_INFO_GAP = 17  # distance from the probe surface [mm], < 0 penetrates
_N_INFO = 18


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


# ---------------------------------------------------------------- kernels


class _Rod(NamedTuple):
    """What the kernels read of a :class:`_Problem`, fixed during a run."""

    h: np.ndarray  # (N,) segment lengths [mm]
    ell: np.ndarray  # (N,) Voronoi lengths of the nodes [mm]
    width: float  # [mm]
    carried: np.ndarray  # (N,) weight moment arm of each segment [mm]
    spring: float  # clamp stiffness [N·mm/rad] (if has_spring)
    has_spring: bool
    centre_x: float  # probe centre [mm]
    centre_z: float
    rho: float  # contact radius [mm]
    has_probe: bool
    mu: float  # Coulomb coefficient
    stick_stiffness: float  # tangential penalty of sticking [N/mm]
    moment_weight: float  # 1/(D·b/l): makes a moment residual dimensionless
    gap_weight: float  # 1/l: makes the gap dimensionless


class _Loads(NamedTuple):
    """The loads of an iterate (ramped in by :func:`_sag` and the cantilever)."""

    tension: float  # dead end load along +x [N]
    line_load: float  # self-weight per length along −z [N/mm]
    active: bool  # the contact is in the active set


class _Reference(NamedTuple):
    """What the kernels read of the last converged step."""

    eps_p: np.ndarray  # (N, n_fibres) plastic strains
    fields: np.ndarray  # its fields (nodes and tangents: the slip's reference)
    friction: float  # its friction force [N]


@njit(cache=True)
def _bending(psi, theta, rod, fibres, eps_p, fields, overstress):
    """Curvatures ``kappa_i = (psi_i − psi_{i−1})/ell_i`` (``psi_{−1} = theta``),
    the moments and tangent stiffnesses of the section law (full width) into
    ``fields``; node 0 carries the clamp spring instead when there is one."""
    h, ell, width = rod.h, rod.ell, rod.width
    kappa, moment, stiff = fields[_ROW_KAPPA], fields[_ROW_MOMENT], fields[_ROW_STIFF]
    before = theta
    for i in range(h.size):
        kappa[i] = (psi[i] - before) / ell[i]
        before = psi[i]
    rotation = kappa[0]
    if rod.has_spring:
        kappa[0] = 0.0  # the spring node keeps an unused, unloaded section
    for i in range(h.size):
        m, c = return_mapping(kappa[i], eps_p[i], fibres, overstress[i])
        moment[i] = m * width
        stiff[i] = c * width / ell[i]
    if rod.has_spring:
        moment[0] = rod.spring * rotation
        stiff[0] = rod.spring


@njit(cache=True)
def _geometry(psi, h, fields):
    """Tangents ``e`` and nodes ``r[i+1] = r[i] + h_i·e_i`` into ``fields``."""
    cos, sin, x, z = fields[_ROW_COS], fields[_ROW_SIN], fields[_ROW_X], fields[_ROW_Z]
    x[0] = z[0] = 0.0
    for i in range(h.size):
        cos[i] = math.cos(psi[i])
        sin[i] = math.sin(psi[i])
        x[i + 1] = x[i] + h[i] * cos[i]
        z[i + 1] = z[i] + h[i] * sin[i]


@njit(cache=True)
def _load_residual(loads, rod, fields):
    """Residual rows without the contact: ``M_i − M_{i+1}`` plus the moments of the
    end load ``T·h_i·sin psi_i`` and of the weight carried downstream
    ``q·h_i·carried_i·cos psi_i``."""
    tension, line_load = loads.tension, loads.line_load
    h, carried = rod.h, rod.carried
    moment, residual = fields[_ROW_MOMENT], fields[_ROW_RESIDUAL]
    n = h.size
    for i in range(n):
        residual[i] = moment[i] - moment[i + 1] if i + 1 < n else moment[i]
        if tension:
            residual[i] += tension * h[i] * fields[_ROW_SIN, i]
        if line_load:
            residual[i] += line_load * h[i] * carried[i] * fields[_ROW_COS, i]


@njit(cache=True)
def _segment_distance(i, centre_x, centre_z, h, fields):
    """Projection of the centre onto segment ``i`` (unclipped) and the distance
    from the centre to the segment's nearest point."""
    cos, sin = fields[_ROW_COS, i], fields[_ROW_SIN, i]
    rel_x, rel_z = centre_x - fields[_ROW_X, i], centre_z - fields[_ROW_Z, i]
    along = cos * rel_x + sin * rel_z
    u = min(max(along, 0.0), h[i])
    dx = centre_x - (fields[_ROW_X, i] + u * cos)
    dz = centre_z - (fields[_ROW_Z, i] + u * sin)
    return along, math.sqrt(dx * dx + dz * dz)


@njit(cache=True)
def _nearest_point(rod, preferred, fields, info):
    """The point of the mid-line nearest to the probe centre, over all segments,
    into ``info``; its levers ``a_n, a_t`` into ``fields``.

    Where the strip is concave towards the probe, the probe centre projects
    onto two neighbouring segments and the nearer one flips between Newton
    iterates; the ``preferred`` segment (−1: none) is kept until the
    projection leaves it (the other segment's overlap is ~rho·kink²).
    """
    h, centre_x, centre_z = rod.h, rod.centre_x, rod.centre_z
    n = h.size
    k, best = 0, math.inf
    for i in range(n):
        _, distance = _segment_distance(i, centre_x, centre_z, h, fields)
        if distance < best:
            k, best = i, distance
    if preferred >= 0:
        along, distance = _segment_distance(preferred, centre_x, centre_z, h, fields)
        if 0.0 < along < h[preferred] and distance - best < _HYSTERESIS * h[preferred]:
            k = preferred
    along, _ = _segment_distance(k, centre_x, centre_z, h, fields)
    cos, sin = fields[_ROW_COS], fields[_ROW_SIN]
    if 0.0 < along < h[k]:
        # Segment case: the normal is the segment's; the signed distance stays
        # meaningful for a Newton iterate that over-shoots the probe centre.
        normal_x, normal_z = -sin[k], cos[k]
        point_x = fields[_ROW_X, k] + along * cos[k]
        point_z = fields[_ROW_Z, k] + along * sin[k]
        distance = normal_x * (centre_x - fields[_ROW_X, k]) + normal_z * (
            centre_z - fields[_ROW_Z, k]
        )
        segment, upstream, reach, u, on_vertex = k, k, k + 1, along, 0.0
    else:
        v = k + 1 if along >= h[k] else k  # the vertex is node v
        point_x, point_z = fields[_ROW_X, v], fields[_ROW_Z, v]
        diff_x, diff_z = centre_x - point_x, centre_z - point_z
        distance = math.hypot(diff_x, diff_z)
        normal_x, normal_z = diff_x / distance, diff_z / distance
        segment, upstream, reach, u, on_vertex = min(v, n - 1), v, v, 0.0, 1.0
    # J_j = h_j·n_j upstream, u·n_k on the contact segment; the tangent is the
    # normal turned by −90°, along the strip away from the clamp.
    tangent_x, tangent_z = normal_z, -normal_x
    for j in range(reach):
        lever = h[j] if j < upstream else u
        jac_x, jac_z = -lever * sin[j], lever * cos[j]
        fields[_ROW_NORMAL_J, j] = normal_x * jac_x + normal_z * jac_z
        fields[_ROW_TANGENT_J, j] = tangent_x * jac_x + tangent_z * jac_z
    info[_INFO_HAS_CONTACT] = 1.0
    info[_INFO_SEGMENT] = segment
    info[_INFO_ON_VERTEX] = on_vertex
    info[_INFO_UPSTREAM] = upstream
    info[_INFO_REACH] = reach
    info[_INFO_U] = u
    info[_INFO_POINT_X] = point_x
    info[_INFO_POINT_Z] = point_z
    info[_INFO_DISTANCE] = distance
    info[_INFO_NORMAL_X] = normal_x
    info[_INFO_NORMAL_Z] = normal_z


@njit(cache=True)
def _friction(lam, rod, previous, info):
    """Coulomb's law by return mapping on the slip of the material point in
    contact since the last step: stick elastically, else slide; into ``info``."""
    before_fields = previous.fields
    upstream, u = int(info[_INFO_UPSTREAM]), info[_INFO_U]
    if info[_INFO_ON_VERTEX]:
        before_x, before_z = before_fields[_ROW_X, upstream], before_fields[_ROW_Z, upstream]
    else:
        k = int(info[_INFO_SEGMENT])
        before_x = before_fields[_ROW_X, k] + u * before_fields[_ROW_COS, k]
        before_z = before_fields[_ROW_Z, k] + u * before_fields[_ROW_SIN, k]
    slip_x, slip_z = info[_INFO_POINT_X] - before_x, info[_INFO_POINT_Z] - before_z
    slip = info[_INFO_NORMAL_Z] * slip_x - info[_INFO_NORMAL_X] * slip_z  # along the tangent
    trial = previous.friction - rod.stick_stiffness * slip
    limit = rod.mu * max(lam, 0.0)
    sticking = abs(trial) <= limit
    info[_INFO_FRICTION] = trial if sticking else math.copysign(limit, trial)
    info[_INFO_STICKING] = 1.0 if sticking else 0.0
    info[_INFO_SLIP_X] = slip_x
    info[_INFO_SLIP_Z] = slip_z


@njit(cache=True)
def _measure(rod, residual, info):
    """Merit (squared norm of the residual scaled by ``moment_weight`` and
    ``gap_weight``) and convergence (each scaled entry within its tolerance)."""
    moment_weight, gap_weight = rod.moment_weight, rod.gap_weight
    n = residual.size - 1
    merit, converged = 0.0, True
    for i in range(n + 1):
        scaled = residual[i] * (moment_weight if i < n else gap_weight)
        merit += scaled * scaled
        converged = converged and abs(scaled) < (_MOMENT_TOLERANCE if i < n else _GAP_TOLERANCE)
    if not math.isfinite(merit):
        merit, converged = math.inf, False
    info[_INFO_MERIT] = merit
    info[_INFO_CONVERGED] = 1.0 if converged else 0.0


# Where each record ends among a kernel's flat arguments (see _unpack).
_LOADS_END = len(_Loads._fields)
_ROD_END = _LOADS_END + len(_Rod._fields)
_FIBRES_END = _ROD_END + len(Fibres._fields)


@njit(cache=True)
def _unpack(flat):
    """The :class:`_Loads` and :class:`_Rod` that lead a kernel's ``*flat``
    arguments (the evaluation's go on with a :class:`~._coating.Fibres` and a
    :class:`_Reference`). Kernels take these records field by field: numba
    type-checks plain arguments several times faster than tuples at each call."""
    return _Loads(*flat[:_LOADS_END]), _Rod(*flat[_LOADS_END:_ROD_END])


@njit(cache=True)
def _evaluate_kernel(psi, lam, theta, preferred, *flat):
    """Residual of equilibrium and of the gap at ``(psi, lam)``: ``fields``,
    ``info`` and the fibres' overstress (see the module's notes)."""
    loads, rod = _unpack(flat)
    fibres, previous = Fibres(*flat[_ROD_END:_FIBRES_END]), _Reference(*flat[_FIBRES_END:])
    n = psi.size
    fields = np.zeros((_N_ROWS, n + 1))
    info = np.zeros(_N_INFO)
    overstress = np.empty(previous.eps_p.shape)
    _bending(psi, theta, rod, fibres, previous.eps_p, fields, overstress)
    _geometry(psi, rod.h, fields)
    _load_residual(loads, rod, fields)
    residual = fields[_ROW_RESIDUAL]
    if rod.has_probe:
        _nearest_point(rod, preferred, fields, info)
        info[_INFO_GAP] = info[_INFO_DISTANCE] - rod.rho
    if rod.has_probe and loads.active:
        reach = int(info[_INFO_REACH])
        for j in range(reach):
            residual[j] += lam * fields[_ROW_NORMAL_J, j]
        if rod.mu:
            _friction(lam, rod, previous, info)
            for j in range(reach):
                residual[j] -= info[_INFO_FRICTION] * fields[_ROW_TANGENT_J, j]
        residual[n] = info[_INFO_GAP]
    else:
        residual[n] = lam  # no probe, or the strip is off it: no contact force
    _measure(rod, residual, info)
    return fields, info, overstress


@njit(cache=True)
def _jacobian_kernel(fields, info, lam, stiff, *flat):
    """The exact Jacobian at an iterate, as :class:`_Jacobian`'s parts.

    ``stiff`` replaces the section tangents (see :func:`_newton`). The
    tridiagonal part: ``dR_i/dpsi`` from the moments (``stiff``), the end load
    ``T·h·cos psi`` and the weight ``−q·h·carried·sin psi``. The contact rows
    ``lam·a_n − f·a_t``: the segments upstream of the contact point turn
    (diagonal ``w = lam·a_t + f·a_n``), the normal turns with its angle
    ``beta`` (``−w ⊗ dbeta``, with ``dbeta = e_k`` inside segment k and
    ``a_t/distance`` at a vertex), the contact segment's lever ``u`` changes
    (segment case), the friction of a sticking point follows the slip
    (``k_s·a_t ⊗ (a_t + dbeta·normal·slip)``), a sliding one ``lam``
    (``−mu·sign(f)·a_t``); the gap row is ``−a_n``.
    """
    loads, rod = _unpack(flat)
    tension, line_load = loads.tension, loads.line_load
    h, carried = rod.h, rod.carried
    n = stiff.size
    diag = np.empty(n)
    for i in range(n):
        diag[i] = stiff[i] + stiff[i + 1] if i + 1 < n else stiff[i]
        if tension:
            diag[i] += tension * h[i] * fields[_ROW_COS, i]
        if line_load:
            diag[i] -= line_load * h[i] * carried[i] * fields[_ROW_SIN, i]
    contact = rod.has_probe and loads.active
    m = int(info[_INFO_REACH]) if contact else 0
    head = np.zeros((m + 1, m + 1))
    for i in range(m):
        head[i, i] = diag[i]
        if i + 1 < m:
            head[i, i + 1] = head[i + 1, i] = -stiff[i + 1]
    if contact:
        _contact_jacobian(head, fields, info, lam, rod.mu, rod.stick_stiffness)
    else:
        head[m, m] = 1.0  # no contact force: the last row is lam = 0
    coupling = -stiff[m] if 0 < m < n else 0.0
    return head, diag[m:].copy(), -stiff[m + 1 :], coupling


@njit(cache=True)
def _contact_jacobian(head, fields, info, lam, mu, stick_stiffness):
    """Add the contact's terms (see :func:`_jacobian_kernel`) to ``head``."""
    m = head.shape[0] - 1
    normal_j, tangent_j = fields[_ROW_NORMAL_J, :m], fields[_ROW_TANGENT_J, :m]
    friction, sticking = info[_INFO_FRICTION], info[_INFO_STICKING] != 0.0
    distance, upstream = info[_INFO_DISTANCE], int(info[_INFO_UPSTREAM])
    slip_normal = (
        info[_INFO_NORMAL_X] * info[_INFO_SLIP_X] + info[_INFO_NORMAL_Z] * info[_INFO_SLIP_Z]
    )
    w = lam * tangent_j + friction * normal_j
    for j in range(upstream):
        head[j, j] += w[j]
    if info[_INFO_ON_VERTEX]:
        dbeta = tangent_j / distance
        for i in range(m):
            for j in range(m):
                head[i, j] -= w[i] * dbeta[j]
                if sticking:
                    head[i, j] += (
                        stick_stiffness * tangent_j[i] * (tangent_j[j] + slip_normal * dbeta[j])
                    )
    else:
        k = m - 1
        for i in range(m):
            head[i, k] -= w[i]
            head[k, i] -= lam * tangent_j[i]
            if sticking:
                for j in range(m):
                    head[i, j] += stick_stiffness * tangent_j[i] * tangent_j[j]
                head[i, k] += stick_stiffness * slip_normal * tangent_j[i]
        head[k, k] += lam * distance + friction * info[_INFO_U]
    for i in range(m):
        head[i, m] = normal_j[i]
        head[m, i] = -normal_j[i]
        if mu and not sticking and lam > 0.0:
            head[i, m] -= mu * np.sign(friction) * tangent_j[i]


@njit(cache=True)
def _tridiagonal_solve(off, diag, rhs):
    """Solve a symmetric tridiagonal system in place of ``rhs`` (n, n_rhs): Gaussian
    elimination with partial pivoting (LAPACK's ``gtsv``); False if singular."""
    n, n_rhs = rhs.shape
    d, lower, upper = diag.copy(), off.copy(), off.copy()
    upper2 = np.zeros(max(n - 2, 0))  # fill-in of row interchanges
    for i in range(n - 1):
        if abs(d[i]) >= abs(lower[i]):
            if d[i] == 0.0:
                return False
            factor = lower[i] / d[i]
            d[i + 1] -= factor * upper[i]
            for c in range(n_rhs):
                rhs[i + 1, c] -= factor * rhs[i, c]
        else:  # interchange rows i and i+1
            factor = d[i] / lower[i]
            d[i], below = lower[i], d[i + 1]
            d[i + 1] = upper[i] - factor * below
            if i < n - 2:
                upper2[i] = upper[i + 1]
                upper[i + 1] = -factor * upper2[i]
            upper[i] = below
            for c in range(n_rhs):
                rhs[i, c], rhs[i + 1, c] = rhs[i + 1, c], rhs[i, c] - factor * rhs[i + 1, c]
    if d[n - 1] == 0.0:
        return False
    for i in range(n - 1, -1, -1):
        for c in range(n_rhs):
            if i + 1 < n:
                rhs[i, c] -= upper[i] * rhs[i + 1, c]
            if i + 2 < n:
                rhs[i, c] -= upper2[i] * rhs[i + 2, c]
            rhs[i, c] /= d[i]
    return True


@njit(cache=True)
def _dense_solve(matrix, rhs):
    """Solve ``matrix·x = rhs`` in place of both by LU with partial pivoting;
    False if singular."""
    n = rhs.size
    for c in range(n):
        pivot = c
        for r in range(c + 1, n):
            if abs(matrix[r, c]) > abs(matrix[pivot, c]):
                pivot = r
        if matrix[pivot, c] == 0.0:
            return False
        if pivot != c:
            for j in range(c, n):
                matrix[c, j], matrix[pivot, j] = matrix[pivot, j], matrix[c, j]
            rhs[c], rhs[pivot] = rhs[pivot], rhs[c]
        for r in range(c + 1, n):
            factor = matrix[r, c] / matrix[c, c]
            if factor != 0.0:
                for j in range(c + 1, n):
                    matrix[r, j] -= factor * matrix[c, j]
                rhs[r] -= factor * rhs[c]
    for r in range(n - 1, -1, -1):
        for j in range(r + 1, n):
            rhs[r] -= matrix[r, j] * rhs[j]
        rhs[r] /= matrix[r, r]
    return True


@njit(cache=True)
def _condensed_solve(head, tail_diagonal, tail_off, coupling, rhs):
    """``J⁻¹·rhs`` from :class:`_Jacobian`'s parts; ``(x, False)`` if ``J`` is singular.

    Static condensation of the tail: solve ``T·[y, z] = [rhs_tail, e_0]``,
    which leaves the head with ``J[m−1, m−1] − c²·z_0`` and
    ``rhs[m−1] − c·y_0``; solve it, then ``x_tail = y − c·x[m−1]·z``.
    """
    m, n = head.shape[0] - 1, rhs.size - 1
    x = np.empty(n + 1)
    reduced = head.copy()
    head_x = np.empty(m + 1)
    head_x[:m] = rhs[:m]
    head_x[m] = rhs[n]
    tail = np.zeros((n - m, 2))
    if n > m:
        tail[:, 0] = rhs[m:n]
        tail[0, 1] = 1.0
        if not _tridiagonal_solve(tail_off, tail_diagonal, tail):
            return x, False
        if m:
            reduced[m - 1, m - 1] -= coupling * coupling * tail[0, 1]
            head_x[m - 1] -= coupling * tail[0, 0]
    if not _dense_solve(reduced, head_x):
        return x, False
    x[:m] = head_x[:m]
    x[n] = head_x[m]
    for i in range(n - m):
        x[m + i] = tail[i, 0] - (coupling * head_x[m - 1] * tail[i, 1] if m else 0.0)
    return x, True


@njit(cache=True)
def _newton_direction(fields, info, lam, stiff, *flat):
    """Newton's step ``−J⁻¹·residual`` and whether ``J`` was regular."""
    head, tail_diagonal, tail_off, coupling = _jacobian_kernel(fields, info, lam, stiff, *flat)
    return _condensed_solve(head, tail_diagonal, tail_off, coupling, -fields[_ROW_RESIDUAL])


@njit(cache=True)
def _secant_kernel(old_fields, new_fields, ell):
    """Section tangents of the new iterate, with the secant slope
    ``ΔM/Δkappa / ell`` where the tangent switched between the two iterates."""
    n = ell.size
    stiff = new_fields[_ROW_STIFF, :n].copy()
    for i in range(n):
        d_kappa = new_fields[_ROW_KAPPA, i] - old_fields[_ROW_KAPPA, i]
        if stiff[i] != old_fields[_ROW_STIFF, i] and abs(d_kappa) > 1e-14:
            d_moment = new_fields[_ROW_MOMENT, i] - old_fields[_ROW_MOMENT, i]
            stiff[i] = d_moment / d_kappa / ell[i]
    return stiff


# ---------------------------------------------------------------- the problem


@dataclass(frozen=True)
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
    normal_j: np.ndarray  # (reach,) a_n = normal·J = −d(gap)/d(psi)
    tangent_j: np.ndarray  # (reach,) a_t = tangent·J


@dataclass(slots=True, eq=False)
class _Evaluation:
    """Residual of the KKT system at one iterate, with what its Jacobian needs.

    ``fields`` and ``info`` as the kernels write them (see the module's notes);
    the properties read them by name. (Not frozen: one is built per iterate,
    and a frozen dataclass's ``__init__`` is several times slower.)
    """

    psi: np.ndarray
    lam: float
    fields: np.ndarray  # (_N_ROWS, N+1)
    info: np.ndarray  # (_N_INFO,)
    overstress: np.ndarray  # (N, n_fibres) of the section law, see return_mapping
    loads: _Loads  # at this iterate
    merit: float
    converged: bool

    @property
    def active(self) -> bool:
        """The contact force acts (False: the strip is off the probe)."""
        return self.loads.active

    @property
    def residual(self) -> np.ndarray:
        """(N+1,): moments [N·mm] then the gap [mm]."""
        return self.fields[_ROW_RESIDUAL]

    @property
    def kappa(self) -> np.ndarray:
        return self.fields[_ROW_KAPPA, :-1]

    @property
    def moment(self) -> np.ndarray:
        return self.fields[_ROW_MOMENT, :-1]

    @property
    def stiff(self) -> np.ndarray:
        return self.fields[_ROW_STIFF, :-1]

    @property
    def friction_n(self) -> float:
        return float(self.info[_INFO_FRICTION])

    @property
    def sticking(self) -> bool:
        return bool(self.info[_INFO_STICKING])

    @property
    def on_segment(self) -> bool:
        """There is a probe and the nearest point lies inside a segment."""
        return bool(self.info[_INFO_HAS_CONTACT]) and not self.info[_INFO_ON_VERTEX]

    @property
    def gap(self) -> float:
        """Of a free strip: distance from the probe surface [mm], < 0 penetrates."""
        return float(self.info[_INFO_GAP])

    @property
    def contact(self) -> _Contact | None:
        """The nearest point of the mid-line to the probe; None without a probe."""
        info = self.info
        if not info[_INFO_HAS_CONTACT]:
            return None
        reach = int(info[_INFO_REACH])
        normal = info[[_INFO_NORMAL_X, _INFO_NORMAL_Z]]
        return _Contact(
            segment=int(info[_INFO_SEGMENT]),
            on_vertex=bool(info[_INFO_ON_VERTEX]),
            upstream=int(info[_INFO_UPSTREAM]),
            u=float(info[_INFO_U]),
            point=info[[_INFO_POINT_X, _INFO_POINT_Z]],
            distance=float(info[_INFO_DISTANCE]),
            normal=normal,
            tangent=np.array([normal[1], -normal[0]]),
            normal_j=self.fields[_ROW_NORMAL_J, :reach],
            tangent_j=self.fields[_ROW_TANGENT_J, :reach],
        )


@dataclass(frozen=True)
class _Configuration:
    """A converged configuration, the reference for the next step's slip."""

    psi: np.ndarray
    lam: float
    state: SectionState
    friction_n: float
    fields: np.ndarray  # of the converged iterate (its nodes and tangents count)
    reference: _Reference = field(init=False, repr=False)  # what the kernels read

    def __post_init__(self) -> None:
        reference = _Reference(self.state.eps_p, self.fields, self.friction_n)
        object.__setattr__(self, "reference", reference)

    @property
    def nodes(self) -> np.ndarray:
        """(N+1, 2) node positions [mm]."""
        return self.fields[[_ROW_X, _ROW_Z]].T


@dataclass(slots=True, eq=False)
class _Jacobian:
    """The Jacobian of the residual, split at the contact's reach ``m``.

    The unknowns ``psi[:m]`` and ``lam`` (the head) are coupled densely by the
    contact. Downstream of the contact point ``psi[m:]`` (the tail) only the
    section law, the end load and the weight act: a symmetric tridiagonal
    block, which meets the head at ``J[m−1, m] = J[m, m−1] = coupling`` alone.
    """

    head: np.ndarray  # (m+1, m+1): rows and columns psi[:m], then lam
    tail_diagonal: np.ndarray  # (N−m,)
    tail_off: np.ndarray  # (N−m−1,) both off-diagonals
    coupling: float

    def dense(self) -> np.ndarray:
        """The full (N+1, N+1) matrix, unknowns ``psi`` then ``lam``."""
        m, n_tail = self.head.shape[0] - 1, self.tail_diagonal.size
        n = m + n_tail
        matrix = np.zeros((n + 1, n + 1))
        order = np.r_[0:m, n]
        matrix[np.ix_(order, order)] = self.head
        matrix[m:n, m:n] = (
            np.diag(self.tail_diagonal) + np.diag(self.tail_off, 1) + np.diag(self.tail_off, -1)
        )
        if m and n_tail:
            matrix[m - 1, m] = matrix[m, m - 1] = self.coupling
        return matrix

    def solve(self, rhs: np.ndarray) -> np.ndarray | None:
        """``J⁻¹·rhs`` (see :func:`_condensed_solve`); None if ``J`` is singular."""
        x, regular = _condensed_solve(
            self.head, self.tail_diagonal, self.tail_off, self.coupling, rhs
        )
        return x if regular else None


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
        # Weight moment arm of each segment: the length it carries downstream.
        self.carried = np.cumsum(h[::-1])[::-1] - 0.5 * h
        self.arc_at_nodes = np.concatenate([[0.0], np.cumsum(h)])
        self.N = h.size
        # No probe (None) is for verification against the cantilever table.
        rho = contact_radius_mm if contact_radius_mm is not None else 0.0
        self.loads = _Loads(float(tension_n), float(line_load_n_mm), True)
        ell = np.empty(self.N)
        ell[0] = h[0] / 2.0
        ell[1:] = 0.5 * (h[:-1] + h[1:])
        if self.spring is not None:
            ell[0] = 1.0  # placeholder: node 0 is the spring, not a section
        self.ell = ell
        stiffness_scale = section.stiffness_nmm * width_mm / bending_length_mm  # D·b/l
        self.elastic_stiff = section.stiffness_nmm * width_mm / self.ell
        if self.spring is not None:
            self.elastic_stiff[0] = self.spring
        # the floor of a node's tangent after a step the line search shortened (_newton)
        self.unloading_stiff = _UNLOADING_FLOOR * self.elastic_stiff
        self.rod = _Rod(
            h=h,
            ell=ell,
            width=float(width_mm),
            carried=self.carried,
            spring=float(self.spring or 0.0),
            has_spring=self.spring is not None,
            centre_x=float(bending_length_mm),
            centre_z=float(rho),
            rho=float(rho),
            has_probe=contact_radius_mm is not None,
            mu=float(friction),
            stick_stiffness=_STICK_STIFFNESS_FACTOR * stiffness_scale / bending_length_mm**2,
            moment_weight=1.0 / stiffness_scale,
            gap_weight=1.0 / bending_length_mm,
        )

    @property
    def active(self) -> bool:
        """The contact is in the active set."""
        return self.loads.active

    @active.setter
    def active(self, value: bool) -> None:
        self.loads = self.loads._replace(active=value)

    @property
    def tension(self) -> float:
        return self.loads.tension

    @tension.setter
    def tension(self, value: float) -> None:
        self.loads = self.loads._replace(tension=float(value))

    @property
    def line_load(self) -> float:
        return self.loads.line_load

    @line_load.setter
    def line_load(self, value: float) -> None:
        self.loads = self.loads._replace(line_load=float(value))

    def configuration(
        self, psi: np.ndarray, lam: float, state: SectionState, friction_n: float
    ) -> _Configuration:
        fields = np.zeros((_N_ROWS, self.N + 1))
        _geometry(psi, self.h, fields)
        return _Configuration(psi, lam, state, friction_n, fields)

    def accept(self, ev: _Evaluation, before: _Configuration) -> _Configuration:
        """The converged iterate ``ev`` of the step from ``before``, as the next
        step's reference (the fibres' plastic strains updated)."""
        state = self.section.updated_state(before.state, ev.overstress)
        return _Configuration(ev.psi, ev.lam, state, ev.friction_n, ev.fields)

    def evaluate(
        self,
        psi: np.ndarray,
        lam: float,
        theta: float,
        previous: _Configuration,
        preferred: int | None = None,
    ) -> _Evaluation:
        """Residual of equilibrium and of the gap at ``(psi, lam)``; ``preferred``:
        the contact segment to keep while the probe centre projects onto it."""
        fields, info, overstress = _evaluate_kernel(
            psi,
            float(lam),
            float(theta),
            -1 if preferred is None else preferred,
            *self.loads,
            *self.rod,
            *self.section.fibres,
            *previous.reference,
        )
        return _Evaluation(
            psi,
            float(lam),
            fields,
            info,
            overstress,
            self.loads,
            float(info[_INFO_MERIT]),
            bool(info[_INFO_CONVERGED]),
        )

    def jacobian(self, ev: _Evaluation, stiff: np.ndarray | None = None) -> np.ndarray:
        """Exact derivative of ``ev.residual`` with respect to ``(psi, lam)``, dense.

        ``stiff`` replaces the section tangents (see :func:`_newton`).
        """
        return self.jacobian_parts(ev, stiff).dense()

    def jacobian_parts(self, ev: _Evaluation, stiff: np.ndarray | None = None) -> _Jacobian:
        """:meth:`jacobian` as its dense head and tridiagonal tail."""
        stiff = ev.stiff if stiff is None else stiff
        parts = _jacobian_kernel(ev.fields, ev.info, ev.lam, stiff, *ev.loads, *self.rod)
        return _Jacobian(*parts)

    def forces(self, ev: _Evaluation) -> tuple[float, float]:
        """Resultant and perpendicular force on the probe [N]: ``lam·n − f·t``."""
        info = ev.info
        if not info[_INFO_HAS_CONTACT] or not ev.active:
            return 0.0, 0.0
        normal_x, normal_z = float(info[_INFO_NORMAL_X]), float(info[_INFO_NORMAL_Z])
        friction = float(info[_INFO_FRICTION])
        on_probe_x = ev.lam * normal_x - friction * normal_z
        on_probe_z = ev.lam * normal_z + friction * normal_x
        return math.hypot(on_probe_x, on_probe_z), on_probe_z


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
    cycling of plain Newton when a fibre sits at its yield point. The
    iterations run compiled (:func:`_newton_kernel`).
    """
    converged, psi, lam, fields, info, overstress = _newton_kernel(
        psi,
        float(lam),
        float(theta),
        problem.ell,
        problem.unloading_stiff,
        *problem.loads,
        *problem.rod,
        *problem.section.fibres,
        *previous.reference,
    )
    if not converged:
        return None
    return _Evaluation(
        psi, lam, fields, info, overstress, problem.loads, float(info[_INFO_MERIT]), True
    )


@njit(cache=True)
def _kept_segment(info, preferred):
    """The contact segment the next iterate keeps (see :func:`_nearest_point`): this
    iterate's where its contact point lies inside a segment, else still ``preferred``
    (−1: none)."""
    if info[_INFO_HAS_CONTACT] and not info[_INFO_ON_VERTEX]:
        return int(info[_INFO_SEGMENT])
    return preferred


@njit(cache=True)
def _newton_kernel(psi, lam, theta, ell, unloading, *flat):
    """:func:`_newton`'s iterations: whether they converged, and the last iterate's
    ``psi``, ``lam``, ``fields``, ``info`` and overstress. ``unloading``: the floor of a
    node's tangent after a step the line search shortened; ``flat`` as
    :func:`_evaluate_kernel`'s."""
    fields, info, overstress = _evaluate_kernel(psi, lam, theta, -1, *flat)
    preferred = _kept_segment(info, -1)
    n = psi.size
    stiff = fields[_ROW_STIFF, :n].copy()  # the section tangents, until a secant replaces them
    best, since_best = info[_INFO_MERIT], 0
    for _ in range(_MAX_NEWTON):
        merit = info[_INFO_MERIT]
        if merit == np.inf:
            break
        if info[_INFO_CONVERGED]:
            return True, psi, lam, fields, info, overstress
        if since_best >= _STALL_ITERATIONS:
            break  # stalled: leave it to _initial_stiffness
        delta, regular = _newton_direction(fields, info, lam, stiff, *flat[:_ROD_END])
        if not regular:
            break
        # Limit the rotation update: the contact search is only valid nearby.
        largest = np.abs(delta[:n]).max()
        scaled = 0.2 / (1e-300 if 1e-300 > largest else largest)
        step = scaled if scaled < 1.0 else 1.0
        full_step = step
        for _ in range(_MAX_BACKTRACKS):
            trial_psi = psi + step * delta[:n]
            trial_lam = lam + step * delta[n]
            trial_fields, trial_info, trial_overstress = _evaluate_kernel(
                trial_psi, trial_lam, theta, preferred, *flat
            )
            preferred = _kept_segment(trial_info, preferred)
            if trial_info[_INFO_MERIT] < (1.0 - 1e-4 * step) * merit:
                break
            step *= 0.5
        stiff = _secant_kernel(fields, trial_fields, ell)
        if step < full_step:
            # A kink stopped the full step: let fully plastic nodes see that
            # they may unload (their tangent is zero on the loading side).
            stiff = np.maximum(stiff, unloading)
        psi, lam, fields, info, overstress = (
            trial_psi,
            trial_lam,
            trial_fields,
            trial_info,
            trial_overstress,
        )
        if info[_INFO_MERIT] < 0.5 * best:
            best, since_best = info[_INFO_MERIT], 0
        else:
            since_best += 1
    return False, psi, lam, fields, info, overstress


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
    ev = problem.evaluate(psi, lam, theta, previous)
    lu = piv = None
    for iteration in range(_MAX_INITIAL_STIFFNESS):
        if ev.merit == math.inf:
            return None
        if ev.converged:
            return ev
        if iteration % _REFACTOR_EVERY == 0:  # the contact geometry drifts slowly
            # LAPACK's getrf and getrs, which scipy.linalg.lu_factor and lu_solve call
            # (the same numbers), without their checks: hundreds of solves a step
            lu, piv, info = dgetrf(problem.jacobian(ev, problem.elastic_stiff))
            if info != 0:  # singular (> 0), or a value LAPACK refused (< 0)
                return None
        delta, _ = dgetrs(lu, piv, -ev.residual)
        preferred = int(ev.info[_INFO_SEGMENT]) if ev.on_segment else None
        ev = problem.evaluate(ev.psi + delta[:-1], ev.lam + delta[-1], theta, previous, preferred)
    return None


def _record(problem: _Problem, ev: _Evaluation, current: _Configuration) -> tuple[float, ...]:
    force, perp = problem.forces(ev)
    info = ev.info
    arc = float(problem.arc_at_nodes[int(info[_INFO_UPSTREAM])] + info[_INFO_U])
    eps_p = current.state.eps_p
    kappa_p = np.abs(problem.section.plastic_curvature(current.state)).max() if eps_p.any() else 0.0
    # The probe bends the strip clockwise (negative curvature): report the
    # clamp moment with the sign of the lifting rotation.
    return (force, perp, ev.lam, arc, -float(ev.moment[0]), float(kappa_p))


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
        at_rest if ev is None else _record(problem, ev, current)
        for ev, current in _march(problem, np.radians(angles_deg))
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


class _Predictor:
    """Extrapolates ``(psi, lam)`` to the next angle from the last converged steps.

    Linearly through the last two states, or quadratically through the last
    three (Newton's divided differences in ``theta``), whichever would have
    predicted the last step's angles better: a smoothly bending strip suits the
    quadratic guess, which then often converges in one Newton iteration; a
    strip turning about a plastic hinge moves linearly between kinks, where the
    linear guess is often already converged.
    """

    def __init__(self, n_unknowns: int) -> None:
        self.slope = np.zeros(n_unknowns)  # first divided difference over the last step
        self.bend = np.zeros(n_unknowns)  # second divided difference over the last two
        self.last_span = 0.0  # the last step [rad]
        self.quadratic = False

    def guess(self, psi: np.ndarray, lam: float, span: float) -> tuple[np.ndarray, float]:
        """The extrapolation ``span`` after the converged ``(psi, lam)``; ``lam >= 0``."""
        curve = self.last_span + span if self.quadratic else 0.0
        return _extrapolate(psi, lam, self.slope, self.bend, span, curve)

    def update(self, before: _Configuration, after: _Evaluation, span: float) -> None:
        """Take in the step of ``span`` from ``before`` to ``after``."""
        quadratic = _update_differences(
            before.psi,
            before.lam,
            after.psi,
            after.lam,
            span,
            self.last_span,
            self.slope,
            self.bend,
        )
        if self.last_span:
            self.quadratic = quadratic
        self.last_span = span


@njit(cache=True)
def _extrapolate(psi, lam, slope, bend, span, curve):
    """``x + (slope + bend·curve)·span`` for ``x = (psi, lam)``, ``lam`` kept ``>= 0``."""
    n = psi.size
    guess = np.empty(n)
    for i in range(n):
        guess[i] = psi[i] + (slope[i] + bend[i] * curve) * span
    return guess, max(lam + (slope[n] + bend[n] * curve) * span, 0.0)


@njit(cache=True)
def _update_differences(before_psi, before_lam, after_psi, after_lam, span, last_span, slope, bend):
    """Newton's divided differences of ``(psi, lam)`` over the step just taken, in
    place; whether the quadratic guess would have predicted its ``psi`` better
    (smaller largest error) than the linear one (without a last step: False)."""
    n = before_psi.size
    linear_miss = quadratic_miss = 0.0
    for i in range(n + 1):
        new = (after_psi[i] - before_psi[i] if i < n else after_lam - before_lam) / span
        if last_span:
            change = new - slope[i]  # the linear guess's error, per span
            if i < n:
                linear_miss = max(linear_miss, abs(change))
                quadratic_miss = max(quadratic_miss, abs(change - bend[i] * (span + last_span)))
            bend[i] = change / (span + last_span)
        slope[i] = new
    return quadratic_miss < linear_miss


def _march(
    problem: _Problem, angles_rad: np.ndarray
) -> Iterator[tuple[_Evaluation | None, _Configuration]]:
    """Rotate the clamp through ``angles_rad``; yield each converged state.

    Each interval is one load step, bisected when Newton fails; the last state
    stands where it is still the equilibrium (:func:`_held`), else the predictor
    extrapolates the last steps (see :class:`_Predictor`). ``None`` stands for
    the unloaded state at 0°.
    """
    n = problem.N
    current = problem.configuration(np.zeros(n), 0.0, problem.section.initial_state(n), 0.0)
    if problem.line_load:
        current = _sag(problem, current)
    predictor = _Predictor(n + 1)
    theta_done = 0.0
    last: _Evaluation | None = None
    for target in angles_rad:
        span, substeps = target - theta_done, 1
        while theta_done < target - 1e-12:
            theta = min(target, theta_done + span / substeps)
            dtheta = theta - theta_done
            ev = _held(problem, last, current, theta)
            if ev is None:
                guess_psi, guess_lam = predictor.guess(current.psi, current.lam, dtheta)
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
            predictor.update(current, ev, dtheta)
            current = problem.accept(ev, current)
            theta_done = theta
            last = ev
        yield last, current


def _held(
    problem: _Problem, last: _Evaluation | None, current: _Configuration, theta: float
) -> _Evaluation | None:
    """The last converged state where it is the equilibrium at ``theta`` too (on the
    probe), else None.

    Where a plastic hinge at the clamp takes the whole rotation, nothing else moves: the
    last state is the equilibrium at the next angle as well, and the path stays there.
    Newton's iterations from the predictor's extrapolation can instead end in another
    equilibrium that the friction at the probe allows — the strip wrapped around it under
    end tension, the contact point near a node: coats 2·10⁻¹² apart in Scoat gave curves
    0.7 N apart past the hinge (``benchmarks/smoothness.py``).
    """
    if last is None or not problem.active:
        return None
    ev = problem.evaluate(current.psi, current.lam, theta, current, _kept_segment(last.info, -1))
    return ev if ev.converged and ev.lam >= 0.0 else None


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
        current = problem.accept(ev, current)
    problem.line_load = load
    assert ev is not None  # the loop ran (four fractions)
    if ev.gap < 0.0:  # cannot happen with the probe above the strip; kept as a guard
        problem.active = True
    return current


def _check_contact(ev: _Evaluation, n_segments: int, theta: float) -> None:
    if not ev.info[_INFO_HAS_CONTACT] or not ev.active:
        return
    if ev.info[_INFO_UPSTREAM] >= n_segments:
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
            current = problem.accept(ev, current)
        load_done = load
        tip = current.nodes[-1]
        tips.append((tip[0], length - tip[1]))
        rotations.append(theta - current.psi[-1])
    return np.array(tips), np.array(rotations)
