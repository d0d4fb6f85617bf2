"""Benchmark of the GP fit and posterior mean: scikit-learn's regressor against ours.

``surrogate.gp._regressor.Regressor`` evaluates the log-marginal likelihood of the
product's kernel (``C · Matern(2.5, ARD) + White``) without scikit-learn's kernel
objects, in one compiled call (the posterior mean: scikit-learn's arithmetic without its
per-call checks). This prints, for training sets of the product's sizes, the time a fit
(one restart, as the curve surrogate's first fit) and a posterior mean of 26 points (one
search batch) take with each, measured in turns in one process, their ratio, and how far
apart the fitted hyperparameters (largest difference of their logarithms) and the means
(largest difference over the means' spread) are.

Run: .venv/bin/python benchmarks/gp_fit.py [--repeats 10]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path[:] = [str(Path(__file__).resolve().parents[1])] + [
    p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent
]

from sklearn.gaussian_process import GaussianProcessRegressor  # noqa: E402

from benchmarks._machine import machine  # noqa: E402
from surrogate.gp._curves import _kernel  # noqa: E402
from surrogate.gp._regressor import Regressor  # noqa: E402

# runs × features; 120 and 230 runs: a diagnosis's refits on a corrected model (test_fidelity)
SIZES = ((10, 4), (20, 4), (40, 5), (80, 5), (120, 5), (230, 5))


def _timed(make, X, y, Z, repeats):
    fits, means, last = [], [], None
    for seed in range(repeats):
        start = time.perf_counter()
        gp = make(seed).fit(X, y)
        fits.append(time.perf_counter() - start)
        start = time.perf_counter()
        mean = gp.posterior_mean(Z) if isinstance(gp, Regressor) else gp.predict(Z)
        means.append(time.perf_counter() - start)
        last = (gp.kernel_.theta, mean)
    return statistics.median(fits), statistics.median(means), last


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    print(machine())
    print(
        f"{'n':>3} {'d':>2} {'fit sklearn':>11} {'fit ours':>9} {'ratio':>6} "
        f"{'mean sklearn':>12} {'mean ours':>9} {'ratio':>6} {'Δ log θ':>8} {'Δ mean':>8}"
    )
    rng = np.random.default_rng(0)
    for n, d in SIZES:
        X = rng.uniform(size=(n, d))
        y = np.sin(3.0 * X).sum(axis=1)
        Z = rng.uniform(size=(26, d))

        def theirs(seed, d=d):
            return GaussianProcessRegressor(
                kernel=_kernel(d), normalize_y=True, n_restarts_optimizer=1, random_state=seed
            )

        def ours(seed, d=d):
            return Regressor(
                kernel=_kernel(d), normalize_y=True, n_restarts_optimizer=1, random_state=seed
            )

        fit_a, mean_a, (theta_a, m_a) = _timed(theirs, X, y, Z, args.repeats)
        fit_b, mean_b, (theta_b, m_b) = _timed(ours, X, y, Z, args.repeats)
        theta_gap = np.abs(theta_a - theta_b).max()
        mean_gap = np.abs(m_a - m_b).max() / max(np.ptp(m_a), 1e-300)
        print(
            f"{n:>3} {d:>2} {fit_a * 1e3:>9.1f}ms {fit_b * 1e3:>7.1f}ms {fit_a / fit_b:>5.2f}x "
            f"{mean_a * 1e6:>10.0f}µs {mean_b * 1e6:>7.0f}µs {mean_a / mean_b:>5.2f}x "
            f"{theta_gap:>8.1e} {mean_gap:>8.1e}"
        )


if __name__ == "__main__":
    main()
