"""Statistics of a misfit against the measurement noise (pure: arrays in, records out).

One place for the tests that the calibration's status and the diagnosis share —
"is this residual what the noise explains?" and the information criterion that
ranks models — and for the diagnosis's own statistics and rules:

- *where* the model fails: the F-test of each cell (a test, an angle band, a value
  of a condition) against the noise, Bonferroni over the cells
  (:func:`failing_cells`);
- *what* the residual follows: one-at-a-time weighted regressions on each column
  and a cubic in the angle, F-tested (:func:`residual_follows`);
- *which* effect is missing: the verdict rules over the ranked candidates
  (:func:`named`, :func:`tied`, :func:`verdict`).

NumPy and SciPy only: the callers turn studies, tables and solver runs into the
arrays these take.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import stats

__all__ = [
    "DECISIVE_DELTA_BIC",
    "HELDOUT_GAIN",
    "NEAR_NOISE",
    "SIGNIFICANCE",
    "Candidate",
    "bic",
    "column_values",
    "failing_cells",
    "misfit_p_value",
    "named",
    "noise_dof",
    "ranking_label",
    "residual_follows",
    "tied",
    "verdict",
]

SIGNIFICANCE = 0.01  # family-wise level of every test (Bonferroni within a family)
DECISIVE_DELTA_BIC = -10.0  # "very strong" evidence (Kass & Raftery 1995)
HELDOUT_GAIN = 0.9  # a named effect cuts the held-out RMSE by ≥ 10 %
NEAR_NOISE = 1.3  # an RMSE within 1.3× noise is explained


def misfit_p_value(rss: float, dof: int, noise: float, dof_noise: float) -> float:
    """P-value of "the residuals are noise": ``(RSS/dof)/s² ~ F(dof, dof_noise)``.

    Parameters
    ----------
    rss : float
        Residual sum of squares [N²].
    dof : int
        Its degrees of freedom (points − fitted parameters).
    noise : float
        The noise level ``s`` [N].
    dof_noise : float
        Degrees of freedom of ``s`` (replicates); ``inf`` for a stated noise level
        (then the test is χ²).
    """
    if dof <= 0:
        return 1.0
    ratio = rss / dof / noise**2
    if math.isinf(dof_noise):
        return float(stats.chi2.sf(ratio * dof, dof))
    return float(stats.f.sf(ratio, dof, dof_noise))


def noise_dof(stated: bool, replicate_dof: int) -> float:
    """Degrees of freedom of the noise level: ``inf`` when stated in the study
    (``[measurements] noise_n``) or unknown, else the replicates'."""
    return math.inf if stated or not replicate_dof else float(replicate_dof)


def bic(rss: float, n: int, k: int) -> float:
    """Bayesian information criterion of a least-squares fit with ``k`` parameters."""
    return n * math.log(rss / n) + k * math.log(n)


# -- where the model fails ----------------------------------------------------------------------
def failing_cells(
    cells: Sequence[tuple[str, str, np.ndarray]],
    residual: np.ndarray,
    noise: float,
    dof_noise: float,
) -> list[dict[str, Any]]:
    """Cells whose misfit the noise does not explain, worst first.

    Parameters
    ----------
    cells : sequence of (kind, name, mask)
        ``mask`` (n,) selects the cell's measured points (``kind``: ``test``,
        ``angle band`` or a condition's column).
    residual : ndarray, (n,)
        Measured minus model [N].
    noise, dof_noise : float
        The noise level [N] and its degrees of freedom (:func:`noise_dof`).
    """
    found = []
    for kind, name, mask in cells:
        r = residual[mask]
        p = misfit_p_value(float(r @ r), r.size, noise, dof_noise)
        if p * len(cells) < SIGNIFICANCE:
            found.append(
                {
                    "kind": kind,
                    "name": name,
                    "rmse_n": float(np.sqrt(np.mean(r**2))),
                    "bias_n": float(np.mean(r)),
                    "p_value": min(1.0, p * len(cells)),
                }
            )
    return sorted(found, key=lambda c: -c["rmse_n"])


# -- what the residual follows ------------------------------------------------------------------
def column_values(values: Sequence[Any]) -> np.ndarray | None:
    """A table column as numbers: text levels in sorted order, else floats (None if mixed)."""
    if all(isinstance(v, str) for v in values):
        levels = sorted(set(values))
        return np.array([levels.index(v) for v in values], dtype=float)
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        return None


def _numeric(values: Sequence[Any], column: str) -> np.ndarray | None:
    """:func:`column_values`, with the rate on a log scale (the rate effect's own axis)."""
    x = column_values(values)
    if x is None or column != "rate_deg_s" or np.any(x <= 0):
        return x
    return np.log(x)


def residual_follows(
    residual: np.ndarray,
    point_test: np.ndarray,
    angle_deg: np.ndarray,
    columns: Mapping[str, Sequence[Any]],
    noise: float,
    *,
    n_tests: int,
) -> list[dict[str, Any]]:
    """Which columns the residual follows, strongest first (Bonferroni-corrected p).

    Each column in turn: a weighted regression of the tests' mean residual on it
    (weights: the tests' point counts), F-tested against what it leaves unexplained
    — or against the noise, whichever is larger — so a decoy that merely
    correlates a little with the real cause is not reported while the misfit is
    far above the noise. The angle: every residual on a cubic in the angle.

    Parameters
    ----------
    residual, point_test, angle_deg : ndarray, (n,)
        Measured minus model [N], the test index and the angle [deg] of every point.
    columns : mapping
        Column name → its value for each of the ``n_tests`` tests (in test-index order).
    noise : float
        The noise level [N], the floor of the unexplained scatter.
    """
    counts = np.bincount(point_test, minlength=n_tests).astype(float)
    bias = np.bincount(point_test, residual, n_tests) / counts
    found = []
    for column, values in columns.items():
        x = _numeric(values, column)
        if x is None or np.ptp(x) == 0 or n_tests < 3:
            continue
        design = np.column_stack([np.ones(n_tests), x])
        found.append(_regression(column, design, bias, counts, noise))
    angle = angle_deg / 90.0
    design = np.column_stack([np.ones_like(angle), angle, angle**2, angle**3])
    found.append(_regression("angle_deg", design, residual, np.ones_like(residual), noise))
    for entry in found:
        entry["p_value"] = min(1.0, entry["p_value"] * len(found))
        entry["significant"] = entry["p_value"] < SIGNIFICANCE
    return sorted(found, key=lambda e: (e["p_value"], -e["f_stat"]))


def _regression(
    name: str, design: np.ndarray, y: np.ndarray, weights: np.ndarray, noise: float
) -> dict[str, Any]:
    """F-test of a weighted least-squares fit against a constant; noise as the floor."""
    w = np.sqrt(weights)
    coef, *_ = np.linalg.lstsq(design * w[:, None], y * w, rcond=None)
    fitted = design @ coef
    mean = np.average(y, weights=weights)
    k = design.shape[1] - 1
    explained = float(np.sum(weights * (fitted - mean) ** 2)) / k
    dof = y.size - design.shape[1]
    scatter = float(np.sum(weights * (y - fitted) ** 2)) / max(dof, 1)
    f_stat = explained / max(scatter, noise**2)
    p = float(stats.f.sf(f_stat, k, dof)) if dof > 0 else 1.0
    return {"covariate": name, "p_value": p, "f_stat": f_stat, "slope_n": float(coef[1])}


# -- which effect is missing --------------------------------------------------------------------
@dataclass(frozen=True)
class Candidate:
    """A candidate effect added to the model and refitted (an entry of the ranking)."""

    effect: str
    rmse_n: float
    heldout_rmse_n: float
    delta_bic: float
    params: dict[str, float]
    confirmed_by: str | None = None  # the expensive solver whose runs the figures are
    # why that calibration ended before a verified local optimum (None: it reached one,
    # or the figures are not an expensive calibration's): its RMSE is then an upper bound
    unsettled: str | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def named(best: Candidate, heldout: float, noise: float | None = None) -> bool:
    """Decisive (ΔBIC < −10) and cuts the held-out error ≥ 10 %; with ``noise``: and
    brings the RMSE near it (nothing left to look for)."""
    decisive = best.delta_bic < DECISIVE_DELTA_BIC and best.heldout_rmse_n < HELDOUT_GAIN * heldout
    return decisive and (noise is None or best.rmse_n <= NEAR_NOISE * noise)


def tied(entry: Candidate, best: Candidate) -> bool:
    """Not decisively worse than the best (ΔBIC within 10 of it)."""
    return entry.delta_bic - best.delta_bic < -DECISIVE_DELTA_BIC


def verdict(
    rmse: float,
    heldout: float,
    noise: float,
    systematic: bool,
    p_value: float,
    ranking: Sequence[Candidate],
    follows: Sequence[Mapping[str, Any]],
    tied_with: Sequence[str] = (),
) -> tuple[dict[str, Any] | None, str]:
    """What the diagnosis concludes: ``(unexplained, text)``.

    No systematic misfit: nothing needed. Else the best candidate is named when
    :func:`named` holds (with the candidates ``tied_with`` it); when none brings the
    error near the noise, the column the residual follows (``follows``, significant
    first) is named as unexplained instead — unless the leader's figures come from a
    calibration that stopped before a verified local optimum (``unsettled``: an
    expensive solver's confirmation, README "Multi-fidelity"): they are then upper
    bounds, and whether an effect is missing is said to be open, with what would tell.
    """
    trail = [f for f in follows if f["significant"]]
    column = trail[0]["covariate"] if trail else None
    if not systematic:
        return None, (
            f"no systematic misfit: RMSE {rmse:.3g} N is what noise {noise:.3g} N explains "
            f"(p = {p_value:.2g}); no effect needed"
        )
    best = ranking[0] if ranking else None
    text = ""
    if best is not None and named(best, heldout):
        text = _named_text(best, heldout, noise, column, tied_with)
        if best.rmse_n <= NEAR_NOISE * noise:
            return None, text
        text += f"; a misfit remains after it ({best.rmse_n / noise:.3g} × noise)"
    leaders = [c for c in ranking if c is best or c.effect in tied_with]
    stopped = next((c for c in leaders if c.unsettled is not None), None)
    if stopped is not None:
        return None, (text + "; " if text else "") + _open_text(stopped, bool(text))
    return _unexplained(rmse, noise, column, trail, text)


def _open_text(leader: Candidate, is_named: bool) -> str:
    """Why a misfit is not called unexplained: a leader's figures come from an expensive
    solver's calibration that stopped before a verified local optimum (upper bounds)."""
    effect, solver = leader.effect, leader.confirmed_by or "the full solver"
    return (
        f"whether {'another' if is_named else 'an'} effect is missing is open: the "
        f"calibration with `{effect}` on {solver} stopped short ({leader.unsettled}), so "
        "its RMSE and ΔBIC are upper bounds and a better fit may exist — a calibration "
        f"with it on {solver} itself (`surrogate calibrate --effect {effect}` with the "
        f"model's other effects and `[solver] multi_fidelity = false`: {solver}'s own "
        "global phase), or `surrogate compare --params …` at values you expect, would tell"
    )


def ranking_label(entry: Mapping[str, Any]) -> str:
    """A ranking entry's effect as the tables show it: marked where its figures are
    upper bounds (``unsettled``: its calibration stopped short)."""
    return f"{entry['effect']} (not settled)" if entry.get("unsettled") else str(entry["effect"])


def _named_text(
    best: Candidate, heldout: float, noise: float, column: str | None, tied_with: Sequence[str]
) -> str:
    why = f"residual follows {column}; " if column else ""
    text = (
        f"missing effect: {best.effect} — {why}`{best.effect}` cuts held-out RMSE "
        f"from {heldout:.3g} N to {best.heldout_rmse_n:.3g} N "
        f"(ΔBIC {best.delta_bic:.0f}), noise {noise:.3g} N"
    )
    if tied_with:
        also = ", ".join(f"`{name}`" for name in tied_with)
        text += (
            f"; {also} {'fits' if len(tied_with) == 1 else 'fit'} as well (ΔBIC within "
            f"{-DECISIVE_DELTA_BIC:.0f}): these data cannot tell them apart"
        )
    return text


def _unexplained(
    rmse: float,
    noise: float,
    column: str | None,
    trail: Sequence[Mapping[str, Any]],
    named_text: str,
) -> tuple[dict[str, Any] | None, str]:
    """The misfit no candidate removes: the column it follows, if any."""
    if column is None:
        return {"covariate": None}, (
            f"unexplained: RMSE {rmse:.3g} N against noise {noise:.3g} N, and the residual "
            "follows no recorded column; no effect in the library explains it"
        )
    unexplained = {"covariate": column, "p_value": trail[0]["p_value"]}
    lead = named_text + ". " if named_text else ""
    return unexplained, (
        f"{lead}unexplained: residual follows {column}; no effect in the library explains "
        "it — write a plug-in effect"
    )
