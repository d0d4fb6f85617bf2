"""CalculiX (``ccx``) as an external full solver of the 2-point bending test.

The deck (after ``shared/calculix.md``, a model that converged to 90°):

- a 2.5-D slice of the strip, ``SLICE_WIDTH_MM`` wide, one C3D20R element
  across; forces are scaled by ``b / SLICE_WIDTH_MM`` to the full width;
- three layers through the thickness: bottom coat, core, top coat; each coat
  occupies the outer Tcoat of its face, as in the built-in solver (design.md
  §3), elastic + ``*PLASTIC`` (ν = 0; an elastic coat gets a huge yield stress,
  since plain ``*ELASTIC`` under NLGEOM is St. Venant–Kirchhoff and softer);
- Scoat is a nominal (engineering) yield stress, as in the built-in rod: ccx's
  ``*PLASTIC`` takes true stress against true plastic strain, and a flat true stress
  under NLGEOM lets the plastic coat's section shrink as it stretches, so the tensile
  coat at the clamp necked in the first element (Considère): its strain jumped from
  15 % to 140 % and the force snapped down by 20 % between 52° and 60° at a thick
  soft coat at 10 mm, at an angle that moved with the increments and the coating.
  The table (:func:`plastic_table`) holds the nominal stress at Scoat (+ the
  hardening), true stress ``(Scoat + H·εp)·exp(εp)``, and the curve is smooth there;
- an orthotropic core, soft in the strip plane (1 MPa) but stiff through the
  thickness and in transverse shear (2000 MPa), so the sandwich bends like the
  built-in rod without the probe crushing it;
- the clamp: ``*RIGID BODY`` on the clamp-edge nodes, reference node on the
  rotation axis, the rotation imposed on its rotation node (−θ about y lifts
  the strip into the probe); lateral displacement held on one face only;
- the probe: a fixed ring of C3D8 elements; surface-to-surface contact with
  the strip's top faces near the probe (linear pressure–overclosure,
  Coulomb friction with a stick slope);
- one ``*STEP, NLGEOM`` / ``*STATIC``, RF of the probe nodes and U of the rotation
  node printed every increment; the history is interpolated to whole degrees;
- ``*CONTROLS, PARAMETERS=CONTACT`` with ``alea = 0``: ccx's contact iterations
  otherwise have a random part (``alea``, default 0.1), and ccx 2.20 then did not
  repeat itself — the same deck, one thread, took other cutbacks above ~75° where
  the coat yields, curves up to 5.8 % apart (``benchmarks/calculix_scatter.py``);
  with ``alea = 0`` four runs of that deck wrote the same ``.dat`` byte for byte;
- the coarse mesh's increments are fixed (``*STATIC, DIRECT``): with automatic ones
  a coat 0.1 % thicker took other cutbacks and its curve moved as much as one 1 %
  thicker (RMS/ε 40 N against 7.4 N), which finite differences and a trust region
  read as gradient; with fixed increments the curve changes in proportion;
- a run that does not reach the angle is run again, first — where fixed increments
  were used — with the same increments up to the last angle the first attempt reached
  and increments of ``RETRY_INCREMENT`` the size from there (one step, the rotation
  and the end load on one ``*AMPLITUDE``: the curve is the first attempt's up to
  there, to ccx's tolerance, not a curve of other increments all the way, which lay
  ~1 % off its neighbours'), then with automatic increments of at most the fixed
  size (the fixed path up to the first increment ccx cuts back: automatic
  ones of 3° put the paper coat's F60 at 15 mm 1.3 % off its neighbours'), then with the
  mesh's own automatic increments (:func:`_next_attempt`): ccx stops short when an increment is
  cut below the minimum (seen at 73–87° on the coarse mesh for yielding coats at 10 and
  15 mm), and with fixed increments its contact iterations can flip between two states
  for ever (seen for 8 minutes at 40 N end tension): more than ``MAX_ITERATIONS`` in
  one attempt of one increment end the attempt (:func:`stalled_increment`, read off
  ccx's ``.cvg`` as it runs and once more at its end, so the same run stops on every
  machine). A run that reaches the angle at first is never re-run, so its curve is the
  deck's; the result's ``increments`` says which attempt's it is, ``retried_after`` why
  the earlier ones stopped ("" for the deck's own).

Notations: x along the undeformed strip from the clamp edge, y across the
width, z up through the thickness; the probe axis is parallel to y.
"""

from __future__ import annotations

import functools
import math
import re
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .._errors import InputDataError, SolverError
from ..effects import ModelState
from ._base import (
    Solver,
    SolverStalled,
    beyond_the_coat,
    check_common_settings,
    command_list,
    curve_result,
    failed_result,
    guarded,
    register_solver,
    run_command,
    work_directory,
)
from ._state import model_state

__all__ = [
    "CALCULIX_MESHES",
    "CalculixMesh",
    "CalculixSolver",
    "calculix_deck",
    "parse_calculix_dat",
    "plastic_table",
]

SLICE_WIDTH_MM = 0.2
DECK_VERSION = "ccx-deck-13"
"""Bump whenever a change to the deck changes results (it keys the cache). 13: the
automatic retry after the fixed ones takes at most the fixed increment (the fixed path
up to a cutback), then the mesh's own; 12: the first retry keeps the first
attempt's increments up to where it stopped; 11: Scoat a nominal yield stress
(:func:`plastic_table`; 10 was tried and reverted); 9: a retry with fixed increments of
half the size before the automatic ones; 8: a stall judged on the whole ``.cvg``; 7:
fixed increments on the coarse mesh; 6: contact without ccx's random part
(``alea = 0``)."""
CONTACT_CONTROLS = "0.001, 0., 100, 60"  # ccx's defaults (delcon, kscalemax, itf2f), alea 0
RETRY_INCREMENT = 0.5  # a retry's increment (fixed; automatic: largest), of the mesh's
MAX_ITERATIONS = 200  # in one attempt of one increment: a fixed increment's contact has
# flipped (automatic increments stop at the deck's 30; fixed ones converged in 3–8)
JOB = "bending"
PLASTIC_STRAINS = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0, 1.5, 2.0)
"""True plastic strains of the coat's ``*PLASTIC`` table (ccx interpolates linearly in
between, a chord above the exponential: 0.1 % at 0.25, and holds the last stress)."""
TABLE_GROWTH = {"BOTCOAT": 1.0, "TOPCOAT": 1.0}
"""Each coat's :func:`plastic_table` growth. The top coat is stretched (the outer face
of the clamp's hinge), the bottom coat compressed. Measured against the built-in rod at
``benchmarks/fidelity.py``'s 10 truths (``benchmarks/calculix_gap.py``, README): with 1
on both, ideal-plastic coats that yield early (the mid coat at 10 mm, at 20 and 40 N;
the hardening coat without its hardening) lie +9 to +30 % above the rod at 60°, +49 %
at 90° and 40 N. Both coats' tables take part: 0 on the compressed coat takes off
≤ 4 points of that, −1 there (the rod's law: a constant nominal force) about half at
40 N and most for the hardening coat without its hardening, but failed at 3 of the 10
and needed retries at 3 (a softening true stress); 0 on both (deck 9's) stays within
−8…+9 % at 60° but needed retries at 4 (the stretched coat necks)."""


@dataclass(frozen=True)
class CalculixMesh:
    """Discretisation and increments of the CalculiX bending model.

    Attributes
    ----------
    element_mm : float
        Element length along the strip through the contact zone.
    clamp_element_mm, clamp_zone_mm : float
        Element length over the first ``clamp_zone_mm`` from the clamp. An
        ideal-plastic hinge localises into the first row of elements at the
        clamp; elements much shorter than the skin thickness there reach skin
        strains of several 100 % and ccx stops (0.1 mm did, at 40°).
    tail_element_mm : float
        Largest element length in the unloaded tail.
    probe_segments : int
        C3D8 elements around the probe's circumference.
    max_increment_deg, initial_increment_deg : float
        Rotation increments of the static step (automatic in between).
    fixed_increment_deg : float or None
        The static step's fixed rotation increment (``*STATIC, DIRECT``); None:
        automatic increments. Its first retry is fixed too (:func:`_next_attempt`);
        the later ones are automatic.
    finer_from_deg : float or None
        With fixed increments: from this angle on (a multiple of the increment),
        increments of ``RETRY_INCREMENT`` the size — a retry's, from where the
        first attempt stopped. None: one size throughout.
    """

    element_mm: float
    clamp_element_mm: float
    clamp_zone_mm: float
    tail_element_mm: float
    probe_segments: int
    max_increment_deg: float
    initial_increment_deg: float
    fixed_increment_deg: float | None = None
    finer_from_deg: float | None = None


CALCULIX_MESHES = {
    "fine": CalculixMesh(0.1, 0.4, 2.0, 1.0, 96, 1.0, 0.5),
    "coarse": CalculixMesh(0.5, 0.5, 0.0, 2.0, 40, 3.0, 1.5, 1.125),
}


# -- the deck ---------------------------------------------------------------------------------
def _strip_stations(
    rig_l_mm: float, free_mm: float, mesh: CalculixMesh
) -> tuple[np.ndarray, float]:
    """Corner x-stations of the strip and the end of the fine zone [mm]."""
    fine_end = min(1.3 * rig_l_mm + 1.0, free_mm)
    end = min(free_mm, fine_end + 0.5 * rig_l_mm + 5.0)
    clamp_end = min(mesh.clamp_zone_mm, 0.5 * fine_end)
    stations = list(np.linspace(0.0, clamp_end, math.ceil(clamp_end / mesh.clamp_element_mm) + 1))
    if mesh.clamp_element_mm > 2.0 * mesh.element_mm and clamp_end > 0.0:  # a transition
        middle = 0.5 * (mesh.clamp_element_mm + mesh.element_mm)
        stations += [clamp_end + middle, clamp_end + 2.0 * middle]
    start = stations[-1]
    n_fine = max(math.ceil((fine_end - start) / mesh.element_mm), 4)
    stations += list(np.linspace(start, fine_end, n_fine + 1)[1:])
    size = (fine_end - start) / n_fine
    while stations[-1] < end - 1e-9:
        size = min(1.5 * size, mesh.tail_element_mm)
        stations.append(min(stations[-1] + size, end))
    return np.array(stations), fine_end


class _Deck:
    """Builds the node/element tables; ``text()`` renders the input deck."""

    def __init__(self, state: ModelState, mesh: CalculixMesh) -> None:
        self.state, self.mesh, self.rig = state, mesh, state.rig
        t, tc = self.rig.thickness_mm, state.tcoat_mm
        self.x, self.fine_end = _strip_stations(
            self.rig.bending_length_mm, self.rig.free_length_mm, mesh
        )
        self.z = np.array([-t / 2, -t / 2 + tc, t / 2 - tc, t / 2])
        self.nx, self.ny, self.nz = 2 * len(self.x) - 1, 3, 7

    # strip nodes on the doubled index grid (i along x, j across, k through)
    def node_id(self, i: int, j: int, k: int) -> int:
        return 1 + (i * self.ny + j) * self.nz + k

    def _coord(self, i: int, j: int, k: int) -> tuple[float, float, float]:
        x = self.x[i // 2] if i % 2 == 0 else 0.5 * (self.x[i // 2] + self.x[i // 2 + 1])
        z = self.z[k // 2] if k % 2 == 0 else 0.5 * (self.z[k // 2] + self.z[k // 2 + 1])
        return x, 0.5 * j * SLICE_WIDTH_MM, z

    def strip_nodes(self) -> list[tuple[int, float, float, float]]:
        return [
            (self.node_id(i, j, k), *self._coord(i, j, k))
            for i in range(self.nx)
            for j in range(self.ny)
            for k in range(self.nz)
            if (i % 2) + (j % 2) + (k % 2) <= 1
        ]

    def strip_elements(self) -> dict[str, list[tuple[int, ...]]]:
        """C3D20R connectivity per layer (element id first)."""
        layers: dict[str, list[tuple[int, ...]]] = {"BOTCOAT": [], "CORE": [], "TOPCOAT": []}
        n = self.node_id
        for a in range(len(self.x) - 1):
            for c, layer in enumerate(layers):
                i0, i1, k0, k1 = 2 * a, 2 * a + 2, 2 * c, 2 * c + 2
                nodes = (
                    n(i0, 0, k0), n(i1, 0, k0), n(i1, 2, k0), n(i0, 2, k0),
                    n(i0, 0, k1), n(i1, 0, k1), n(i1, 2, k1), n(i0, 2, k1),
                    n(i0 + 1, 0, k0), n(i1, 1, k0), n(i0 + 1, 2, k0), n(i0, 1, k0),
                    n(i0 + 1, 0, k1), n(i1, 1, k1), n(i0 + 1, 2, k1), n(i0, 1, k1),
                    n(i0, 0, k0 + 1), n(i1, 0, k0 + 1), n(i1, 2, k0 + 1), n(i0, 2, k0 + 1),
                )  # fmt: skip
                layers[layer].append((1 + 3 * a + c, *nodes))
        return layers

    def probe(self) -> tuple[list[tuple[int, float, float, float]], list[tuple[int, ...]]]:
        """Ring of C3D8 (ξ around, η outward, ζ across): nodes and elements."""
        base = self.node_id(self.nx, 0, 0) + 1000
        m = self.mesh.probe_segments
        radius = self.rig.probe_radius_mm
        xc, zc = self.rig.bending_length_mm, 0.5 * self.rig.thickness_mm + radius
        ys = (-0.5 * SLICE_WIDTH_MM, 1.5 * SLICE_WIDTH_MM)
        radii = (0.7 * radius, radius)

        def nid(s: int, r: int, y: int) -> int:
            return base + ((s % m) * 2 + r) * 2 + y

        nodes = [
            (nid(s, r, y), xc + radii[r] * math.cos(phi), ys[y], zc + radii[r] * math.sin(phi))
            for s in range(m)
            for phi in [2.0 * math.pi * s / m]
            for r in range(2)
            for y in range(2)
        ]
        elements: list[tuple[int, ...]] = [
            (
                base + s,
                nid(s, 0, 0),
                nid(s + 1, 0, 0),
                nid(s + 1, 1, 0),
                nid(s, 1, 0),
                nid(s, 0, 1),
                nid(s + 1, 0, 1),
                nid(s + 1, 1, 1),
                nid(s, 1, 1),
            )
            for s in range(m)
        ]
        return nodes, elements

    def text(self) -> str:
        probe_nodes, probe_elements = self.probe()
        layers = self.strip_elements()
        ref, rot = probe_nodes[-1][0] + 10, probe_nodes[-1][0] + 11
        lines = [
            "** 2-point bending of a coated webbing strip (written by surrogate)",
            f"** slice {SLICE_WIDTH_MM} mm wide; forces x {self.rig.width_mm / SLICE_WIDTH_MM:g}",
            "*NODE, NSET=NALL",
        ]
        lines += [_node_line(*node) for node in self.strip_nodes()]
        lines += ["*NODE, NSET=PROBEN"] + [_node_line(*node) for node in probe_nodes]
        lines += ["*NODE, NSET=REFN", _node_line(ref, 0.0, 0.0, 0.0)]
        lines += ["*NODE, NSET=ROTN", _node_line(rot, 0.0, 0.0, 0.0)]
        for layer, elements in layers.items():
            lines.append(f"*ELEMENT, TYPE=C3D20R, ELSET={layer}")
            for element in elements:
                lines += [_ints(element[:16]), _ints(element[16:])]
        lines.append("*ELEMENT, TYPE=C3D8, ELSET=PROBE")
        lines += [_ints(element) for element in probe_elements]
        lines += self._sets(layers["TOPCOAT"], probe_elements)
        lines += self._materials()
        lines += self._constraints(ref, rot)
        lines += self._contact()
        lines += self._amplitude(self.rig.max_angle_deg)
        lines += self._step(rot)
        return "\n".join(lines) + "\n"

    def _sets(self, top: list[tuple[int, ...]], probe_elements: list[tuple[int, ...]]) -> list[str]:
        clamp = [self.node_id(0, j, k) for j in range(3) for k in range(7) if j % 2 + k % 2 <= 1]
        face = [
            self.node_id(i, 0, k)
            for i in range(1, self.nx)
            for k in range(self.nz)
            if i % 2 + k % 2 <= 1
        ]
        low, high = 0.75 * self.rig.bending_length_mm, self.fine_end
        slave = [e[0] for a, e in enumerate(top) if self.x[a + 1] > low and self.x[a] < high]
        lines = ["*NSET, NSET=CLAMP", *_chunks(clamp)]
        lines += ["*NSET, NSET=YFACE", *_chunks(face)]
        lines += ["*SURFACE, NAME=STRIPTOP, TYPE=ELEMENT"] + [f"{e}, S2" for e in slave]
        lines += ["*SURFACE, NAME=PROBESURF, TYPE=ELEMENT"]
        lines += [f"{e[0]}, S5" for e in probe_elements]
        return lines

    def _materials(self) -> list[str]:
        state = self.state
        lines = []
        for layer, growth in TABLE_GROWTH.items():  # one material per coat, named after it
            lines += [f"*MATERIAL, NAME={layer}", "*ELASTIC", f"{state.ecoat_mpa:.9g}, 0."]
            lines += ["*PLASTIC"] + [
                f"{stress:.9g}, {strain:g}" for stress, strain in plastic_table(state, growth)
            ]
        return [
            *lines,
            "*MATERIAL, NAME=CORE",
            "*ELASTIC, TYPE=ENGINEERING CONSTANTS",
            "1., 1., 2000., 0., 0., 0., 0.5, 2000.",
            "0.5, 0.",
            "*MATERIAL, NAME=RIGID",
            "*ELASTIC",
            "210000., 0.3",
            "*SOLID SECTION, ELSET=BOTCOAT, MATERIAL=BOTCOAT",
            "*SOLID SECTION, ELSET=TOPCOAT, MATERIAL=TOPCOAT",
            "*SOLID SECTION, ELSET=CORE, MATERIAL=CORE",
            "*SOLID SECTION, ELSET=PROBE, MATERIAL=RIGID",
        ]

    def _constraints(self, ref: int, rot: int) -> list[str]:
        return [
            f"*RIGID BODY, NSET=CLAMP, REF NODE={ref}, ROT NODE={rot}",
            "*BOUNDARY",
            "PROBEN, 1, 3",
            f"{ref}, 1, 3",
            f"{rot}, 1, 1",
            f"{rot}, 3, 3",
            "YFACE, 2, 2",
        ]

    def _contact(self) -> list[str]:
        stiffness = 1000.0  # N/mm³: overclosure ~1e-3 mm at the contact pressures here
        lines = [
            "*SURFACE INTERACTION, NAME=PROBECONTACT",
            "*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR",
            f"{stiffness:g}",
        ]
        if self.rig.friction > 0.0:
            lines += ["*FRICTION", f"{self.rig.friction:.9g}, {stiffness / 10:g}"]
        lines += [
            "*CONTACT PAIR, INTERACTION=PROBECONTACT, TYPE=SURFACE TO SURFACE",
            "STRIPTOP, PROBESURF",
        ]
        return lines

    def _step(self, rot: int) -> list[str]:
        span = self.rig.max_angle_deg
        lines = [
            "*STEP, NLGEOM, INC=5000",
            # more iterations (IC 16 → 30) and cutbacks (IA 5 → 15) per increment than
            # ccx's defaults, for the yielding, frictional contact increments
            "*CONTROLS, PARAMETERS=TIME INCREMENTATION",
            "4, 8, 9, 30, 10, 4, 0, 15",
            # no random part in the contact iterations: the same deck, the same curve
            "*CONTROLS, PARAMETERS=CONTACT",
            CONTACT_CONTROLS,
            *self._static(span),
            f"*BOUNDARY{self._on_amplitude(span)}",
            f"{rot}, 2, 2, {-math.radians(span):.12g}",
        ]
        lines += self._end_load()
        lines += [
            "*NODE PRINT, NSET=PROBEN, TOTALS=ONLY",
            "RF",
            "*NODE PRINT, NSET=ROTN",
            "U",
            "*END STEP",
        ]
        return lines

    def _split(self, span: float) -> tuple[int, int] | None:
        """A retry's fixed increments: how many of the mesh's size up to
        ``finer_from_deg`` and of ``RETRY_INCREMENT`` the size after it; None: one
        size throughout."""
        fixed, start = self.mesh.fixed_increment_deg, self.mesh.finer_from_deg
        if fixed is None or start is None or not 0.0 < start < span:
            return None
        finer = RETRY_INCREMENT * fixed
        return round(start / fixed), math.ceil((span - start) / finer - 1e-9)

    def _amplitude(self, span: float) -> list[str]:
        """The rotation (and end load) against step time where the increments change
        size: every increment is one step-time unit of ``*STATIC, DIRECT``."""
        split, start = self._split(span), self.mesh.finer_from_deg
        if split is None or start is None:
            return []
        first, rest = split
        return [
            "*AMPLITUDE, NAME=ROTATION",
            f"0., 0., {first / (first + rest):.12g}, {start / span:.12g}, 1., 1.",
        ]

    def _on_amplitude(self, span: float) -> str:
        return "" if self._split(span) is None else ", AMPLITUDE=ROTATION"

    def _static(self, span: float) -> list[str]:
        mesh = self.mesh
        split = self._split(span)
        if split is not None:
            return ["*STATIC, DIRECT", f"{1.0 / sum(split):.12g}, 1."]
        if mesh.fixed_increment_deg is not None:
            return ["*STATIC, DIRECT", f"{min(mesh.fixed_increment_deg, span) / span:.9g}, 1."]
        return [
            "*STATIC",
            f"{min(mesh.initial_increment_deg, span) / span:.9g}, 1., 1e-6, "
            f"{min(mesh.max_increment_deg, span) / span:.9g}",
        ]

    def _end_load(self) -> list[str]:
        """The rig's dead end load along +x, consistent nodal forces on the end face."""
        tension = self.state.rig.tension_n * SLICE_WIDTH_MM / self.rig.width_mm
        if tension <= 0.0:
            return []
        i = self.nx - 1
        loads: dict[int, float] = {}
        for c in range(3):
            share = tension * (self.z[c + 1] - self.z[c]) / self.rig.thickness_mm
            k0, k1 = 2 * c, 2 * c + 2
            corners = [(0, k0), (2, k0), (2, k1), (0, k1)]
            middles = [(1, k0), (2, k0 + 1), (1, k1), (0, k0 + 1)]
            for j, k in corners:
                loads[self.node_id(i, j, k)] = loads.get(self.node_id(i, j, k), 0.0) - share / 12
            for j, k in middles:
                loads[self.node_id(i, j, k)] = loads.get(self.node_id(i, j, k), 0.0) + share / 3
        cload = f"*CLOAD{self._on_amplitude(self.rig.max_angle_deg)}"  # with the rotation
        return [cload] + [f"{node}, 1, {value:.9g}" for node, value in sorted(loads.items())]


def plastic_table(state: ModelState, growth: float = 1.0) -> list[tuple[float, float]]:
    """A coat's ``*PLASTIC`` rows (true stress [MPa], true plastic strain):
    ``(Scoat + H·εp)·exp(growth·εp)`` at ``PLASTIC_STRAINS``, with the linear hardening
    ``H = Ecoat·ratio/(1 − ratio)`` against plastic strain.

    ``growth`` 1 (the deck's, :data:`TABLE_GROWTH`) makes Scoat a nominal yield stress in
    tension: plastic flow keeps the volume (the elastic part has ν = 0), so a section
    stretched by ``exp(εp)`` shrinks by as much and carries ``Scoat + H·εp`` per unit of
    its undeformed area — the stretched coat does not neck, as the rod's does not.
    ``growth`` 0 is a flat true stress (deck 9's); −1 would be a nominal yield stress in
    compression, a softening true stress ccx does not converge with."""
    ratio = state.hardening_ratio
    modulus = state.ecoat_mpa * ratio / (1.0 - ratio) if ratio > 0.0 else 0.0
    return [
        ((state.scoat_mpa + modulus * strain) * math.exp(growth * strain), strain)
        for strain in PLASTIC_STRAINS
    ]


def _node_line(node: int, x: float, y: float, z: float) -> str:
    return f"{node}, {x:.9g}, {y:.9g}, {z:.9g}"


def _ints(values: tuple[int, ...] | list[int]) -> str:
    return ", ".join(str(v) for v in values)


def _chunks(values: list[int], size: int = 16) -> list[str]:
    return [_ints(values[i : i + size]) + "," for i in range(0, len(values), size)]


def calculix_deck(state: ModelState, *, mesh: str | CalculixMesh = "coarse") -> str:
    """The CalculiX input deck (``.inp`` text) of one bending run.

    Parameters
    ----------
    state : ModelState
        Coating [MPa, mm], hardening ratio and rig (see :func:`model_state`).
    mesh : {"coarse", "fine"} or CalculixMesh
        The discretisation (``CALCULIX_MESHES``).
    """
    if isinstance(mesh, str):
        if mesh not in CALCULIX_MESHES:
            raise InputDataError(
                f"[solver] mesh must be one of {', '.join(CALCULIX_MESHES)}, got {mesh!r}"
            )
        mesh = CALCULIX_MESHES[mesh]
    refused = refusal(state)
    if refused is not None:
        raise InputDataError(refused)
    return _Deck(state, mesh).text()


def refusal(state: ModelState) -> str | None:
    """Why the deck cannot model ``state`` (None when it can): it has no bare-webbing
    stiffness, self-weight or compliant clamp."""
    effect = beyond_the_coat(state)
    if effect == "membrane_bending":
        return (
            "the calculix solver has no bare-webbing bending stiffness (membrane_bending); "
            "use the builtin solver for that effect"
        )
    if effect is not None:
        return (
            f"the calculix deck models neither self-weight nor a compliant clamp ({effect}); "
            "use the builtin solver for that effect"
        )
    return None


# -- the output -------------------------------------------------------------------------------
_HEADER = re.compile(
    r"^\s*(total force \(fx,fy,fz\)|displacements \(vx,vy,vz\)) for set (\S+)"
    r" and time\s+(\S+)",
    re.IGNORECASE,
)


@dataclass(frozen=True)
class CalculixHistory:
    """Per converged increment: step time, probe reaction (slice) and clamp rotation.

    ``probe_force_n`` has shape (n, 3): total reaction of the probe nodes in the
    slice; ``rotation_rad`` (n,): displacement dof 2 of the rotation node, i.e.
    the rotation about y (negative lifts the strip).
    """

    time: np.ndarray
    probe_force_n: np.ndarray
    rotation_rad: np.ndarray


def parse_calculix_dat(text: str) -> CalculixHistory:
    """Parse the ``.dat`` file written by ``*NODE PRINT`` (RF totals, U of ROTN).

    Blocks look like::

         total force (fx,fy,fz) for set PROBEN and time  0.1000000E-01

               -1.2E-03  0.0E+00  3.4E-02
    """
    forces: dict[float, list[float]] = {}
    rotations: dict[float, float] = {}
    lines = text.splitlines()
    for index, line in enumerate(lines):
        match = _HEADER.match(line)
        if not match:
            continue
        time = float(match.group(3))
        values = _next_numbers(lines, index + 1)
        if match.group(1).lower().startswith("total force"):
            forces[time] = values[-3:]
        elif match.group(2).upper() == "ROTN":
            rotations[time] = values[2]  # node id, ux, uy, uz
    times = sorted(set(forces) & set(rotations))
    return CalculixHistory(
        np.array(times),
        np.array([forces[t] for t in times]).reshape(-1, 3),
        np.array([rotations[t] for t in times]),
    )


def _next_numbers(lines: list[str], start: int) -> list[float]:
    for line in lines[start:]:
        if line.strip():
            return [float(v) for v in line.split()]
    raise SolverError("ccx .dat file ends inside a block; the run was cut off")


def ccx_failure(stdout: str, returncode: int) -> str:
    """ccx's own reason for a run that stopped: its first ``*ERROR`` line."""
    for line in stdout.splitlines():
        if "*ERROR" in line.upper():
            return line.strip()
    tail = [line.strip() for line in stdout.splitlines() if line.strip()][-1:]
    return f"ccx exited with code {returncode}" + (f" ({tail[0]})" if tail else "")


# -- the solver -------------------------------------------------------------------------------
@register_solver
class CalculixSolver(Solver):
    """CalculiX ``ccx`` on the deck of :func:`calculix_deck`.

    Settings (``[solver]`` in a study file, ``inputs["solver_settings"]``):
    ``mesh`` (``coarse``/``fine``, default coarse), ``command`` (default
    ``ccx``), ``timeout_s`` (default 1800), ``threads`` (OMP threads, default 1),
    ``keep_workdir``, ``workdir_root``.
    """

    name: ClassVar[str] = "calculix"
    version: ClassVar[str] = DECK_VERSION
    settings_keys: ClassVar[tuple[str, ...]] = (
        "mesh",
        "command",
        "timeout_s",
        "threads",
        "keep_workdir",
        "workdir_root",
    )

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        checked = super().check_settings(settings)
        if checked.get("mesh", "coarse") not in CALCULIX_MESHES:
            raise InputDataError(
                f"[solver] mesh must be one of {', '.join(CALCULIX_MESHES)}, "
                f"got {checked['mesh']!r}"
            )
        check_common_settings(checked)
        return checked

    def solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        return guarded(lambda: self._solve(inputs))

    def refuses(self, state: ModelState) -> str | None:
        return refusal(state)

    def _solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        settings = self.check_settings(inputs.get("solver_settings") or {})
        state = model_state(inputs)
        mesh = CALCULIX_MESHES[settings.get("mesh", "coarse")]
        reasons: list[str] = []
        attempt: CalculixMesh | None = mesh
        while attempt is not None:
            result = self._attempt(state, attempt, settings)
            if result.get("status") != "failed":  # a timeout raises: not retried
                return {
                    **result,
                    "increments": _increments(attempt),
                    "retried_after": "; ".join(reasons),  # "": the deck's own attempt
                }
            said = "with" if not reasons else "again with"
            reasons.append(f"{said} {_increments(attempt)}: {result['reason']}")
            attempt = _next_attempt(mesh, attempt, result["reached_deg"], state.rig.max_angle_deg)
        return failed_result("; ".join(reasons))

    def _attempt(
        self, state: ModelState, mesh: CalculixMesh, settings: Mapping[str, Any]
    ) -> dict[str, Any]:
        """One ccx run of the deck: the curve, or a failed result saying why."""
        deck = calculix_deck(state, mesh=mesh)
        threads = str(int(settings.get("threads", 1)))
        with work_directory(settings, prefix="ccx-") as workdir:
            (workdir / f"{JOB}.inp").write_text(deck, encoding="utf-8")
            convergence = functools.partial(stalled_increment, workdir / f"{JOB}.cvg")
            try:
                done = run_command(
                    [*command_list(settings.get("command", "ccx")), "-i", JOB],
                    cwd=workdir,
                    timeout_s=float(settings.get("timeout_s", 1800.0)),
                    env={"OMP_NUM_THREADS": threads, "CCX_NPROC_EQUATION_SOLVER": threads},
                    stalled=convergence,
                )
                # the rule once more at the end: whether ccx finished between two looks
                # or not, the same .cvg gives the same verdict
                why = convergence()
                if why is None and (done.returncode != 0 or "*ERROR" in done.stdout.upper()):
                    why = (
                        f"ccx did not reach {state.rig.max_angle_deg:g}°: "
                        f"{ccx_failure(done.stdout, done.returncode)}"
                    )
            except SolverStalled as stalled:
                why = str(stalled)
            dat = workdir / f"{JOB}.dat"
            text = dat.read_text(encoding="utf-8", errors="replace") if dat.exists() else ""
        history = parse_calculix_dat(text)
        if why is not None:
            reached = -math.degrees(history.rotation_rad[-1]) if history.time.size else 0.0
            return {
                **failed_result(f"{why} (last converged {reached:.2f}°)"),
                "reached_deg": reached,
            }
        return _curve(history, state)


def _next_attempt(
    mesh: CalculixMesh, last: CalculixMesh, reached_deg: float, span_deg: float
) -> CalculixMesh | None:
    """The deck a run tries after ``last`` stopped at ``reached_deg`` of ``span_deg``
    (None: none is left).

    After the mesh's own fixed increments: the same ones up to the last whole increment
    reached and ``RETRY_INCREMENT`` the size from there (from the start where not even
    one was reached). After that, or where the whole span was reached and the last
    increment still failed (the same deck would again): automatic increments of at most
    the fixed size, starting with it — the fixed attempt's path up to the first
    increment ccx cuts back (at the paper coat at 15 mm, F60 4.1735 N against
    the neighbour's 4.1734 N of fixed increments, where automatic ones of at most 3°
    gave 4.122 N). Then the mesh's own automatic increments (at most 3° on the coarse
    mesh). A mesh of automatic increments (the fine one) tries at most ``RETRY_INCREMENT``
    of its largest after its own."""
    automatic = replace(mesh, fixed_increment_deg=None, finer_from_deg=None)
    fixed = mesh.fixed_increment_deg
    if fixed is None:
        if last != mesh:
            return None
        return replace(
            mesh,
            max_increment_deg=RETRY_INCREMENT * mesh.max_increment_deg,
            initial_increment_deg=min(
                mesh.initial_increment_deg, RETRY_INCREMENT * mesh.max_increment_deg
            ),
        )
    along = replace(
        automatic,
        max_increment_deg=fixed,
        initial_increment_deg=min(mesh.initial_increment_deg, fixed),
    )
    if last == mesh:
        # the history's rotation is the imposed one to ~1e-5 of an increment
        start = fixed * math.floor(reached_deg / fixed + 1e-3)
        if start >= span_deg - 1e-6 * fixed:
            return along
        if start > 0.0:
            return replace(mesh, finer_from_deg=start)
        return replace(mesh, fixed_increment_deg=RETRY_INCREMENT * fixed)
    if last.fixed_increment_deg is not None:
        return along
    if last == along and along != automatic:
        return automatic
    return None


def _increments(mesh: CalculixMesh) -> str:
    fixed = mesh.fixed_increment_deg
    if fixed is not None and mesh.finer_from_deg is not None:
        return (
            f"fixed increments of {fixed:g}° to {mesh.finer_from_deg:g}°, "
            f"then {RETRY_INCREMENT * fixed:g}°"
        )
    if fixed is not None:
        return f"fixed increments of {fixed:g}°"
    return f"automatic increments of at most {mesh.max_increment_deg:g}°"


def stalled_increment(cvg: Path) -> str | None:
    """Why a ccx run will not finish or is not to be trusted, from its convergence file
    ``cvg`` (one line an iteration: step, increment, attempt, iteration …): more than
    ``MAX_ITERATIONS`` in one attempt of one increment, anywhere in the file — a rule of
    the file alone, so a run stopped while it ran and one that finished between two
    looks get the same verdict. None otherwise."""
    try:
        lines = cvg.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return None
    counts = Counter(  # a half-written last line waits for the next look
        tuple(fields[:3])
        for fields in map(str.split, lines)
        if len(fields) >= 5 and fields[0].isdigit()
    )
    for (_, increment, attempt), count in counts.items():
        if count > MAX_ITERATIONS:
            return (
                f"ccx's contact did not settle: more than {MAX_ITERATIONS} iterations in "
                f"increment {increment} (attempt {attempt})"
            )
    return None


def _curve(history: CalculixHistory, state: ModelState) -> dict[str, Any]:
    scale = state.rig.width_mm / SLICE_WIDTH_MM
    angle = -np.degrees(history.rotation_rad)
    force = history.probe_force_n * scale
    magnitude = np.hypot(force[:, 0], force[:, 2])
    perpendicular = np.abs(force[:, 2])
    return curve_result(angle, magnitude, perpendicular, state.rig.max_angle_deg)


def write_deck(path: Path, inputs: Mapping[str, Any], *, mesh: str = "coarse") -> Path:
    """Write the deck of ``inputs`` to ``path`` (for inspection or a manual ``ccx`` run)."""
    path.write_text(calculix_deck(model_state(inputs), mesh=mesh), encoding="utf-8")
    return path
