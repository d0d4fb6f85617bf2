"""Moment–curvature law of the coated webbing section.

Notations
---------
t       webbing thickness [mm]; the mid-line is inextensible, so a fibre at
        height ``z`` above it has the strain ``kappa * z``.
z1, z2  the coat layer occupies ``z1 <= |z| <= z2`` with ``z2 = t/2`` and
        ``z1 = t/2 - Tcoat``.
E, S    coat Young's modulus and yield stress [MPa].
H       plastic (kinematic) hardening modulus [MPa]; 0 is ideal plasticity.
kappa   curvature [1/mm], positive when the strip bends towards +z.
M       bending moment per unit width [N·mm/mm].
eps_p   plastic strain of each fibre, shape ``(n_points, n_fibres)``.

The two layers are antisymmetric under bending, so only the top layer's fibres
are stored and the moment is twice the top layer's.  The integral through the
layer uses Gauss–Legendre fibres: exact for the elastic stiffness ``D`` (a
quadratic in ``z``) and for the fully plastic moment ``Mp`` (linear in ``z``);
the short partially plastic transition between first yield and ``Mp`` is
resolved fibre by fibre.  Each fibre is a 1-D elastic–plastic element with
return mapping, so unloading is elastic from the stored plastic strain.

The return mapping is compiled (numba, cached on disk): the rod solver calls
it at every node of every Newton iterate, where numpy's per-call overhead on
arrays of a few hundred entries would dominate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from ._section import bending_stiffness, plastic_moment

__all__ = [
    "CoatingSection",
    "Fibres",
    "SectionState",
    "return_mapping",
]

_DEFAULT_FIBRES = 6


@dataclass(frozen=True)
class SectionState:
    """Plastic strain of every fibre at every material point."""

    eps_p: np.ndarray  # (n_points, n_fibres)


class Fibres(NamedTuple):
    """What :func:`return_mapping` reads of a :class:`CoatingSection`."""

    E: float  # coat modulus [MPa]
    S: float  # yield stress [MPa]
    H: float  # kinematic hardening modulus [MPa]
    D0: float  # extra elastic bending stiffness per unit width [N·mm]
    z: np.ndarray  # (n_fibres,) heights of the top layer's fibres [mm]
    moment_arm: np.ndarray  # (n_fibres,) 2·z·w [mm²]
    tangent_arm: np.ndarray  # (n_fibres,) 2·z²·w [mm³]


@njit(cache=True)
def return_mapping(
    kappa: float, eps_p: np.ndarray, fibres: Fibres, overstress: np.ndarray
) -> tuple[float, float]:
    """Moment and tangent per unit width at one point, by the fibres' return mapping.

    ``eps_p`` (n_fibres,) are the point's plastic strains. Each fibre's relative stress
    (trial stress minus the back stress ``H·eps_p``) is
    ``q = E·(kappa·z − eps_p) − H·eps_p``; it yields where ``|q| > S``, by the
    overstress ``q − clip(q, −S, S)`` (written to ``overstress``, shape
    (n_fibres,)), which raises its plastic strain by ``overstress/(E + H)``.
    Its stress is ``E·(kappa·z − eps_p_new)``, its tangent modulus ``E`` or,
    yielding, ``E·H/(E + H)``; both integrate over both layers with the
    Gauss–Legendre weights (``moment_arm = 2·z·w``, ``tangent_arm = 2·z²·w``).
    """
    E, S, H, D0, z, moment_arm, tangent_arm = fibres
    plastic_modulus = E * H / (E + H)
    moment = D0 * kappa
    tangent = D0
    for f in range(z.size):
        relative = E * (kappa * z[f] - eps_p[f]) - H * eps_p[f]
        excess = abs(relative) - S
        if excess > 0.0:
            overstress[f] = math.copysign(excess, relative)
            stress = E * (kappa * z[f] - (eps_p[f] + overstress[f] / (E + H)))
            tangent += plastic_modulus * tangent_arm[f]
        else:
            overstress[f] = 0.0
            stress = E * (kappa * z[f] - eps_p[f])
            tangent += E * tangent_arm[f]
        moment += stress * moment_arm[f]
    return moment, tangent


@njit(cache=True)
def _respond(
    kappa: np.ndarray, eps_p: np.ndarray, fibres: Fibres
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`return_mapping` at every point: moments, tangents, overstresses."""
    moment = np.empty(kappa.size)
    tangent = np.empty(kappa.size)
    overstress = np.empty(eps_p.shape)
    for i in range(kappa.size):
        moment[i], tangent[i] = return_mapping(kappa[i], eps_p[i], fibres, overstress[i])
    return moment, tangent, overstress


@dataclass(frozen=True)
class CoatingSection:
    """Elastic–plastic coat layers on both faces of an inextensible core.

    Parameters
    ----------
    ecoat_mpa, scoat_mpa, tcoat_mm, thickness_mm
        Coat modulus and yield stress [MPa], coat and webbing thickness [mm].
    hardening_modulus_mpa
        Linear kinematic hardening modulus ``H`` (0: ideal plasticity).
    extra_stiffness_nmm
        Elastic bending stiffness per unit width added in parallel (e.g. the
        bare webbing's own), ``M += D0·kappa``.
    n_fibres
        Gauss–Legendre points through each coat layer.
    """

    ecoat_mpa: float
    scoat_mpa: float
    tcoat_mm: float
    thickness_mm: float
    hardening_modulus_mpa: float = 0.0
    extra_stiffness_nmm: float = 0.0
    n_fibres: int = _DEFAULT_FIBRES
    _fibres: Fibres = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        xi, wi = np.polynomial.legendre.leggauss(self.n_fibres)
        z2 = self.thickness_mm / 2.0
        z1 = z2 - self.tcoat_mm
        z = z1 + (xi + 1.0) * 0.5 * self.tcoat_mm
        w = wi * 0.5 * self.tcoat_mm
        fibres = Fibres(
            float(self.ecoat_mpa),
            float(self.scoat_mpa),
            float(self.hardening_modulus_mpa),
            float(self.extra_stiffness_nmm),
            z,
            2.0 * z * w,
            2.0 * z * z * w,
        )
        object.__setattr__(self, "_fibres", fibres)

    @property
    def stiffness_nmm(self) -> float:
        """Elastic bending stiffness per unit width ``D`` [N·mm] (exact)."""
        coat = bending_stiffness(self.ecoat_mpa, self.tcoat_mm, self.thickness_mm)
        return coat + self.extra_stiffness_nmm

    @property
    def plastic_moment_nmm(self) -> float:
        """Fully plastic moment of the coat per unit width ``Mp`` [N·mm/mm] (exact)."""
        return plastic_moment(self.scoat_mpa, self.tcoat_mm, self.thickness_mm)

    @property
    def fibres(self) -> Fibres:
        """What :func:`return_mapping` reads of this section."""
        return self._fibres

    def initial_state(self, n_points: int) -> SectionState:
        """A virgin section at ``n_points`` material points."""
        return SectionState(np.zeros((n_points, self.n_fibres)))

    def respond(
        self, kappa: np.ndarray, state: SectionState
    ) -> tuple[np.ndarray, np.ndarray, SectionState]:
        """Moment, tangent and updated state for curvatures ``kappa``.

        Parameters
        ----------
        kappa : ndarray, shape (n_points,)
            Total curvature at each material point [1/mm].
        state : SectionState
            The last converged state (it is not modified).

        Returns
        -------
        moment : ndarray, shape (n_points,)
            Bending moment per unit width [N·mm/mm].
        tangent : ndarray, shape (n_points,)
            Consistent tangent ``dM/dkappa`` [N·mm].
        new_state : SectionState
            State after the return mapping, to be kept once the step converges.
        """
        kappa = np.ascontiguousarray(kappa, dtype=float)
        moment, tangent, overstress = _respond(kappa, state.eps_p, self.fibres)
        return moment, tangent, self.updated_state(state, overstress)

    def updated_state(self, state: SectionState, overstress: np.ndarray) -> SectionState:
        """The state after yielding by ``overstress`` (see :func:`return_mapping`):
        ``eps_p + overstress/(E + H)``."""
        return SectionState(
            state.eps_p + overstress / (self.ecoat_mpa + self.hardening_modulus_mpa)
        )

    def plastic_curvature(self, state: SectionState) -> np.ndarray:
        """Curvature left at zero moment after elastic unloading [1/mm].

        The stiffness-weighted mean of the fibres' plastic curvatures
        ``eps_p / z``: ``2·E·∫ eps_p·z dz / D``; zero for a virgin section.
        """
        return state.eps_p @ self._fibres.moment_arm * (self.ecoat_mpa / self.stiffness_nmm)
