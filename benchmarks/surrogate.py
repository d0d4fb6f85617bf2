"""Benchmark of the GP surrogate (design.md §6).

For LHS training sets of 10, 20, 40 and 64 points over the paper's ranges
(several seeds each), the error on held-out solver runs: median relative error
of F60, mean absolute error of θsat, coverage of the 95 % intervals, and the
median per-curve RMS error of the predicted curve; also the LOO figures the fit
reports, side by side. Targets with 20 points: F60 ≤ 2 %, θsat MAE ≤ 3°,
coverage 85–99 %.

Run: .venv/bin/python benchmarks/surrogate.py [--held-out 240] [--seeds 5] [--jobs 2]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

# Run as a script, this file's folder comes first on sys.path and its name
# would shadow the package: put the repository root first instead.
sys.path[:] = [str(Path(__file__).resolve().parents[1])] + [
    p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent
]

from surrogate import PAPER_SPACE, make_design  # noqa: E402
from surrogate.identify._commands import fit_surrogate  # noqa: E402
from surrogate.solvers._batch import evaluate_design  # noqa: E402

SIZES = (10, 20, 40, 64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--held-out", type=int, default=240)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    test = evaluate_design(
        make_design("lhs", n=args.held_out, seed=12345), PAPER_SPACE, jobs=args.jobs, progress=False
    )
    ok = test.ok
    X_test = ok[list(PAPER_SPACE.names)].to_numpy()
    f60, theta = ok.f60_n.to_numpy(), ok.theta_sat_deg.to_numpy()
    _, curves = test.curve_matrix()
    print(f"held-out set: {len(ok)} solver runs (LHS seed 12345), {test.n_failed} failed")
    print(
        f"{'n':>3} {'F60 med err':>11} {'F60 cov95':>9} {'θsat MAE':>9} {'θsat cov95':>10} "
        f"{'curve RMS':>9} | {'LOO F60':>8} {'LOO θsat':>8} {'LOO cov F60/θ':>13}"
    )
    for n in SIZES:
        rows = []
        for seed in range(args.seeds):
            train = evaluate_design(
                make_design("lhs", n=n, seed=seed), PAPER_SPACE, jobs=args.jobs, progress=False
            )
            model = fit_surrogate(train, seed=seed)
            pred = model.predict(X_test, return_std=True)
            curve = model.predict_curve(X_test)
            cv = model.cross_validate()
            per_curve = np.sqrt(np.mean((curve[:, 1:] / curves[:, 1:] - 1.0) ** 2, axis=1))
            rows.append(
                (
                    np.median(np.abs(pred["f60_n"] / f60 - 1.0)),
                    np.mean(
                        np.abs(np.log(f60) - np.log(pred["f60_n"])) <= 1.96 * pred["log_f60_std"]
                    ),
                    np.mean(np.abs(pred["theta_sat_deg"] - theta)),
                    np.mean(
                        np.abs(theta - pred["theta_sat_deg"]) <= 1.96 * pred["theta_sat_deg_std"]
                    ),
                    np.median(per_curve),
                    cv["f60_n"]["loo_median_rel_err"],
                    cv["theta_sat_deg"]["loo_mae"],
                    cv["f60_n"]["coverage95"],
                    cv["theta_sat_deg"]["coverage95"],
                )
            )
        m = [statistics.median(column) for column in zip(*rows, strict=True)]
        print(
            f"{n:>3} {100 * m[0]:>10.2f}% {100 * m[1]:>8.0f}% {m[2]:>8.2f}° {100 * m[3]:>9.0f}% "
            f"{100 * m[4]:>8.2f}% | {100 * m[5]:>7.2f}% {m[6]:>7.2f}° "
            f"{100 * m[7]:>6.0f}%/{100 * m[8]:.0f}%"
        )
        if n == 20:
            twenty = m
    print(f"(medians over {args.seeds} training seeds)")
    ok_f60 = twenty[0] <= 0.02
    ok_theta = twenty[2] <= 3.0
    ok_cov = 0.85 <= twenty[1] <= 0.99 and 0.85 <= twenty[3] <= 0.99
    print(
        f"targets at 20 points: F60 <= 2 % {'met' if ok_f60 else 'MISSED'}, "
        f"theta_sat MAE <= 3 deg {'met' if ok_theta else 'MISSED'}, "
        f"coverage 85-99 % {'met' if ok_cov else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
