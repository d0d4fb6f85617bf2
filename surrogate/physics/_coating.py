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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["CoatingSection", "SectionState", "bending_stiffness", "plastic_moment"]

_DEFAULT_FIBRES = 6


def bending_stiffness(ecoat_mpa: float, tcoat_mm: float, thickness_mm: float) -> float:
    """Elastic bending stiffness per unit width, ``D = 2/3·E·(z2³ − z1³)`` [N·mm]."""
    z2 = thickness_mm / 2.0
    z1 = z2 - tcoat_mm
    return 2.0 / 3.0 * ecoat_mpa * (z2**3 - z1**3)


def plastic_moment(scoat_mpa: float, tcoat_mm: float, thickness_mm: float) -> float:
    """Fully plastic moment per unit width, ``Mp = S·Tcoat·(t − Tcoat)`` [N·mm/mm]."""
    return scoat_mpa * tcoat_mm * (thickness_mm - tcoat_mm)


@dataclass(frozen=True)
class SectionState:
    """Plastic strain of every fibre at every material point."""

    eps_p: np.ndarray  # (n_points, n_fibres)


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
    _z: np.ndarray = field(init=False, repr=False, compare=False)
    _w: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        xi, wi = np.polynomial.legendre.leggauss(self.n_fibres)
        z2 = self.thickness_mm / 2.0
        z1 = z2 - self.tcoat_mm
        object.__setattr__(self, "_z", z1 + (xi + 1.0) * 0.5 * self.tcoat_mm)
        object.__setattr__(self, "_w", wi * 0.5 * self.tcoat_mm)

    @property
    def stiffness_nmm(self) -> float:
        """Elastic bending stiffness per unit width ``D`` [N·mm] (exact)."""
        coat = bending_stiffness(self.ecoat_mpa, self.tcoat_mm, self.thickness_mm)
        return coat + self.extra_stiffness_nmm

    @property
    def plastic_moment_nmm(self) -> float:
        """Fully plastic moment of the coat per unit width ``Mp`` [N·mm/mm] (exact)."""
        return plastic_moment(self.scoat_mpa, self.tcoat_mm, self.thickness_mm)

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
        E, S, H = self.ecoat_mpa, self.scoat_mpa, self.hardening_modulus_mpa
        strain = kappa[:, None] * self._z[None, :]
        eps_p = state.eps_p
        relative = E * (strain - eps_p) - H * eps_p  # trial stress minus back stress
        excess = np.abs(relative) - S
        plastic = excess > 0.0
        d_eps_p = np.where(plastic, excess / (E + H), 0.0) * np.sign(relative)
        eps_p_new = eps_p + d_eps_p
        stress = E * (strain - eps_p_new)
        modulus = np.where(plastic, E * H / (E + H), E)
        zw = self._z * self._w
        moment = 2.0 * stress @ zw + self.extra_stiffness_nmm * kappa
        tangent = 2.0 * modulus @ (self._z * zw) + self.extra_stiffness_nmm
        return moment, tangent, SectionState(eps_p_new)

    def plastic_curvature(self, state: SectionState) -> np.ndarray:
        """Curvature left at zero moment after elastic unloading [1/mm].

        The stiffness-weighted mean of the fibres' plastic curvatures
        ``eps_p / z``; zero for a virgin section.
        """
        coat_d = bending_stiffness(self.ecoat_mpa, self.tcoat_mm, self.thickness_mm)
        moment_locked = 2.0 * self.ecoat_mpa * state.eps_p @ (self._z * self._w)
        return moment_locked / (coat_d + self.extra_stiffness_nmm)
