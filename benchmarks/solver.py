"""Benchmark of the built-in full solver (design.md §6).

Prints the median wall time of one default 0–90° curve (paper optimum,
elastic–plastic, μ = 0.1, 1° output) over ``--runs`` runs, and the worst
relative error against every verification reference at the default
discretisation. Run: ``.venv/bin/python benchmarks/solver.py``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import pandas as pd

import surrogate
from surrogate.physics import (
    CoatingSection,
    default_mesh,
    solve_cantilever,
    solve_rod,
    uniform_mesh,
)

REFERENCE = Path(__file__).resolve().parents[1] / "tests" / "reference"
L, B, T = 10.0, 38.0, 1.2
POINT_PROBE_MM = 1e-3


def time_default_curve(runs: int) -> list[float]:
    surrogate.simulate(1.0, 0.2, 0.012)  # warm-up
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        surrogate.simulate(1.0, 0.2, 0.012)
        times.append(time.perf_counter() - start)
    return times


def elastica_errors() -> dict[str, float]:
    table = pd.read_csv(REFERENCE / "elastica.csv", comment="#")
    section = CoatingSection(1000.0, 1e9, 0.012, T)
    unit = section.stiffness_nmm * B / L**2
    errors = {}
    for mu, rows in table.groupby("mu"):
        angles = np.concatenate(([0.0], rows.angle_deg.to_numpy()))
        run = solve_rod(
            section,
            angles,
            segment_lengths_mm=default_mesh(35.0, L),
            width_mm=B,
            bending_length_mm=L,
            contact_radius_mm=POINT_PROBE_MM,
            friction=mu,
        )
        worst = max(
            np.max(np.abs(getattr(run, attr)[1:] / unit / rows[column] - 1.0))
            for attr, column in (
                ("normal_force_n", "normal"),
                ("force_n", "resultant"),
                ("force_perp_n", "perp"),
            )
        )
        errors[f"elastica mu={mu:g}"] = float(worst)
    return errors


def cantilever_error() -> float:
    table = pd.read_csv(REFERENCE / "cantilever.csv", comment="#")
    section = CoatingSection(1000.0, 1e9, 0.012, T)
    length, width = 20.0, 10.0
    loads = table.alpha.to_numpy() * section.stiffness_nmm * width / length**2
    tips, rotation = solve_cantilever(
        section, loads, segment_lengths_mm=uniform_mesh(length, 0.4), width_mm=width
    )
    return float(
        max(
            np.max(np.abs(tips[:, 0] / length / table.w_over_L - 1)),
            np.max(np.abs(tips[:, 1] / length / table.u_over_L - 1)),
            np.max(np.abs(rotation / table.tip_rotation_rad - 1)),
        )
    )


def small_angle_error() -> float:
    section = CoatingSection(1000.0, 1e9, 0.012, T)
    angles = np.array([0.0, 0.5, 1.0])
    run = solve_rod(
        section,
        angles,
        segment_lengths_mm=default_mesh(35.0, L),
        width_mm=B,
        bending_length_mm=L,
        contact_radius_mm=POINT_PROBE_MM,
        friction=0.0,
    )
    expected = 3 * section.stiffness_nmm * B * np.radians(angles[1:]) / L**2
    return float(np.max(np.abs(run.force_n[1:] / expected - 1)))


def rigid_plastic_error() -> float:
    section = CoatingSection(400_000.0, 50.0, 0.05, T)
    angles = np.arange(0.0, 91.0)
    run = solve_rod(
        section,
        angles,
        segment_lengths_mm=default_mesh(35.0, L),
        width_mm=B,
        bending_length_mm=L,
        contact_radius_mm=POINT_PROBE_MM,
        friction=0.0,
    )
    limit = B * section.plastic_moment_nmm / L
    return float(np.max(np.abs(run.force_perp_n[angles >= 10] / limit - 1)))


def mesh_convergence() -> tuple[list[float], float]:
    """RMS error of the default 0–90° curve vs a mesh 8× finer; fitted order."""
    section = CoatingSection(1000.0, 200.0, 0.012, T)

    def curve(fraction: float) -> np.ndarray:
        mesh = default_mesh(35.0, L, fine_fraction=fraction)
        return solve_rod(
            section,
            np.arange(0.0, 91.0),
            segment_lengths_mm=mesh,
            width_mm=B,
            bending_length_mm=L,
            contact_radius_mm=1.6,
            friction=0.1,
        ).force_n

    reference = curve(1 / 200)
    fractions = [1 / 6.25, 1 / 12.5, 1 / 25, 1 / 50]
    errors = [
        float(np.sqrt(np.mean((curve(f) - reference) ** 2) / np.mean(reference**2)))
        for f in fractions
    ]
    order = float(np.polyfit(np.log(fractions), np.log(errors), 1)[0])
    return errors, order


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=30)
    args = parser.parse_args()
    times = time_default_curve(args.runs)
    median_ms = 1000 * statistics.median(times)
    print(
        f"default curve (paper optimum, elastic-plastic, mu=0.1, 0-90 deg by 1 deg): "
        f"median {median_ms:.1f} ms over {args.runs} runs "
        f"(min {1000 * min(times):.1f}, max {1000 * max(times):.1f}); target <= 50 ms"
    )
    errors = elastica_errors()
    errors["cantilever"] = cantilever_error()
    errors["small-angle 3*D*b*theta/l^2"] = small_angle_error()
    errors["rigid-plastic b*Mp/l"] = rigid_plastic_error()
    for name, value in errors.items():
        print(f"  error vs {name:<28} {100 * value:.3f} %")
    print(
        f"worst error against the references: {100 * max(errors.values()):.3f} % (target <= 0.5 %)"
    )
    mesh_errors, order = mesh_convergence()
    print(
        "curve RMS error vs an 8x finer mesh at h = l/6.25, l/12.5, l/25 (default), l/50: "
        + ", ".join(f"{100 * e:.3f} %" for e in mesh_errors)
        + f"; observed order {order:.2f}"
    )
    coarse = surrogate.simulate(1.0, 0.2, 0.012, rig=surrogate.Rig(element_size_mm=2.5))
    fine = surrogate.simulate(1.0, 0.2, 0.012)
    print(
        f"system-model mesh (element_size_mm=2.5): F60 {coarse.f60_n:.3f} N "
        f"vs {fine.f60_n:.3f} N default ({100 * (coarse.f60_n / fine.f60_n - 1):+.1f} %)"
    )


if __name__ == "__main__":
    main()
