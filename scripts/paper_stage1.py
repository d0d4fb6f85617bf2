"""Reproduce the paper's stage 1 with the built-in solver.

Writes, under data/:
- paper_stage1_design.csv: the 64 Table-1 cases with their CAE-IDs;
- paper_stage1_samples.csv (+ _curves.csv, .json): the sample set;
- figures/paper_stage1_curves.png: all 64 curves against the target;
- figures/paper_stage1_sensitivity.png: one-at-a-time sensitivity of Ecoat,
  Tcoat and Scoat around the paper's optimum.

Run: .venv/bin/python scripts/paper_stage1.py [--jobs 2]
The target is the built-in solver's F60 at the paper's optimum (the measured
force is not published), see studies/paper_coating.toml.
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import surrogate
from surrogate._io import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"
FIGURES = DATA / "figures"
OPTIMUM = {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    FIGURES.mkdir(parents=True, exist_ok=True)
    design = surrogate.paper_stage1_design()
    buffer = io.StringIO()
    design.to_csv(buffer, index=False)
    atomic_write_text(DATA / "paper_stage1_design.csv", buffer.getvalue())
    result = surrogate.doe(
        "paper", run=True, jobs=args.jobs, out=DATA / "paper_stage1_samples.csv", progress=True
    )
    print(f"stage 1: {result.n_ok} ok, {result.n_failed} failed, {result.solver_calls} solved")
    samples = surrogate.SampleSet.read(DATA / "paper_stage1_samples.csv")
    target = surrogate.simulate(**OPTIMUM).f60_n
    plot_curves(samples, target)
    plot_sensitivity(target)
    ok = samples.ok
    close = ok[np.abs(ok.f60_n / target - 1) <= 0.1]
    print(f"target F60 = {target:.3f} N; cases within 10 %: {', '.join(close.case_id)}")


def plot_curves(samples: surrogate.SampleSet, target: float) -> None:
    runs = samples.ok
    angles, curves = samples.curve_matrix(runs.run_id.to_numpy())
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), sharex=True, sharey=True)
    colours = dict(
        zip([0.5, 1.0, 2.0, 4.0], ["tab:blue", "tab:green", "tab:orange", "tab:red"], strict=True)
    )
    styles = dict(zip([0.05, 0.1, 0.2, 0.4], [":", "-.", "--", "-"], strict=True))
    for ax, tcoat in zip(axes.flat, [0.01, 0.025, 0.05, 0.1], strict=True):
        mask = np.isclose(runs.tcoat_mm.to_numpy(), tcoat)
        for row, curve in zip(runs[mask].itertuples(), curves[mask], strict=True):
            ax.plot(angles, curve, color=colours[row.ecoat_gpa], ls=styles[row.scoat_gpa], lw=1.2)
        ax.plot([60], [target], "k*", ms=12, label=f"target F60 = {target:.2f} N")
        ax.axvline(80, color="grey", lw=0.8)
        ax.set_title(f"Tcoat = {tcoat} mm")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
    for ax in axes[1]:
        ax.set_xlabel("fixture rotation [deg]")
    for ax in axes[:, 0]:
        ax.set_ylabel("probe force [N]")
    handles = [plt.Line2D([], [], color=c, label=f"Ecoat {e} GPa") for e, c in colours.items()]
    handles += [
        plt.Line2D([], [], color="k", ls=s, label=f"Scoat {v} GPa") for v, s in styles.items()
    ]
    handles += [plt.Line2D([], [], color="k", marker="*", ls="", ms=10, label="target")]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8)
    fig.suptitle("Paper stage 1: 64 full-factorial cases, built-in solver")
    fig.tight_layout(rect=(0, 0.07, 1, 0.96))
    fig.savefig(FIGURES / "paper_stage1_curves.png", dpi=110)
    plt.close(fig)


def plot_sensitivity(target: float) -> None:
    levels = {
        "ecoat_gpa": [0.5, 1.0, 2.0, 4.0],
        "tcoat_mm": [0.006, 0.012, 0.025, 0.05],
        "scoat_gpa": [0.05, 0.1, 0.2, 0.4],
    }
    labels = {"ecoat_gpa": "Ecoat [GPa]", "tcoat_mm": "Tcoat [mm]", "scoat_gpa": "Scoat [GPa]"}
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), sharey=True)
    for ax, (name, values) in zip(axes, levels.items(), strict=True):
        for value, colour in zip(
            values, plt.cm.viridis(np.linspace(0, 0.9, len(values))), strict=True
        ):
            curve = surrogate.simulate(**{**OPTIMUM, name: value})
            ax.plot(
                curve.angle_deg,
                curve.force_n,
                color=colour,
                label=f"{value:g}" + (" (optimum)" if value == OPTIMUM[name] else ""),
            )
        ax.plot([60], [target], "k*", ms=12)
        ax.set_title(f"one at a time: {labels[name]}")
        ax.set_xlabel("fixture rotation [deg]")
        ax.legend(title=labels[name], fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("probe force [N]")
    fig.suptitle("Sensitivity around the paper's optimum (1 GPa, 0.2 GPa, 0.012 mm)")
    fig.tight_layout()
    fig.savefig(FIGURES / "paper_stage1_sensitivity.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
