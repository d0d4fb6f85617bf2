"""The GP surrogate: interpolation, LOO against a hand-made split, JSON round trip."""

import json

import numpy as np
import pytest
from sklearn.gaussian_process import GaussianProcessRegressor

from surrogate import PAPER_SPACE, CoatingSurrogate, InputDataError, SampleSet
from surrogate.identify._commands import fit_surrogate


@pytest.fixture(scope="module")
def samples(tmp_path_factory):
    from surrogate import make_design
    from surrogate.solvers._batch import evaluate_design

    design = make_design("lhs", n=20, seed=5)
    return evaluate_design(design, PAPER_SPACE, progress=False)


@pytest.fixture(scope="module")
def model(samples):
    return fit_surrogate(samples)


def test_fit_returns_self_and_learned_state_ends_in_underscore(samples):
    model = CoatingSurrogate(PAPER_SPACE)
    assert not any(k.endswith("_") for k in vars(model))  # __init__ only stores arguments
    ok = samples.ok
    fitted = model.fit(ok[list(PAPER_SPACE.names)].to_numpy(), ok.f60_n, ok.theta_sat_deg)
    assert fitted is model and hasattr(model, "f60_gp_")


def test_interpolates_its_training_data(samples, model):
    ok = samples.ok
    pred = model.predict(ok[list(PAPER_SPACE.names)].to_numpy(), return_std=True)
    # Up to the fitted noise, which is bounded to ≤ 10× its floor (0.1 % on F60,
    # the 1° grid on θsat): the GP may not smooth the solver's data away.
    for gp, fitted, target in (
        (model.f60_gp_, np.log(pred["f60_n"]), np.log(ok.f60_n)),
        (model.theta_gp_, pred["theta_sat_deg"], ok.theta_sat_deg),
    ):
        noise_sd = np.sqrt(gp.kernel_.k2.noise_level) * gp.y_std_
        assert noise_sd <= 10 * gp.noise_sd * (1 + 1e-9)
        np.testing.assert_array_less(np.abs(fitted - target), 3 * noise_sd)
    assert np.max(np.abs(pred["f60_n"] / ok.f60_n - 1)) < 0.02
    # The curve GPs interpolate the scores; what remains is the basis truncation.
    _angles, curves = samples.curve_matrix()
    log_curves = np.log(curves[:, 1:])
    projected = (
        model.curve_mean_
        + (log_curves - model.curve_mean_) @ model.curve_basis_.T @ model.curve_basis_
    )
    predicted = model.predict_curve(ok[list(PAPER_SPACE.names)].to_numpy())
    np.testing.assert_allclose(predicted[:, 1:], np.exp(projected), rtol=1e-3)
    assert np.all(predicted[:, 0] == 0.0)
    error = np.abs(predicted[:, 1:] / curves[:, 1:] - 1)
    assert np.max(error) < 0.08  # at the saturation knee
    assert np.median(error) < 0.005


def test_loo_matches_a_hand_made_split(model):
    gp = model.f60_gp_
    mean, std = gp.loo()
    Z = model.features_.transform(model.X_train_)
    yn = (np.log(model.f60_train_) - gp.y_mean_) / gp.y_std_
    for i in (0, 7, 19):
        keep = np.arange(len(yn)) != i
        refit = GaussianProcessRegressor(kernel=gp.kernel_, optimizer=None, normalize_y=False).fit(
            Z[keep], yn[keep]
        )
        m, s = refit.predict(Z[i : i + 1], return_std=True)
        # (sklearn's WhiteKernel puts the noise in the predictive variance too)
        assert mean[i] == pytest.approx(m[0] * gp.y_std_ + gp.y_mean_, abs=1e-8)
        assert std[i] == pytest.approx(s[0] * gp.y_std_, rel=1e-6)


def test_cross_validation_figures_from_the_loo(model):
    cv = model.cross_validate()
    mean, _std = model.f60_gp_.loo()
    expected = np.median(np.abs(np.exp(mean) / model.f60_train_ - 1))
    assert cv["f60_n"]["loo_median_rel_err"] == pytest.approx(expected)
    assert 0.0 <= cv["f60_n"]["coverage95"] <= 1.0
    assert cv["f60_n"]["loo_median_rel_err"] < 0.05  # 20 LHS points: a few per cent


def test_json_round_trip_predicts_identically(model, tmp_path):
    points = PAPER_SPACE.from_unit(np.random.default_rng(0).random((50, 3)))
    path = model.save(tmp_path / "model.json")
    text = path.read_text()
    again = CoatingSurrogate.load(path)
    first, second = model.predict(points, return_std=True), again.predict(points, return_std=True)
    for key in first:
        np.testing.assert_array_equal(first[key], second[key])
    np.testing.assert_array_equal(model.predict_curve(points), again.predict_curve(points))
    assert json.loads(text)["format"] == "webbing-surrogate/gp"
    assert b"\x80" not in path.read_bytes()  # data, not a pickle


def test_damaged_model_file_is_refused(model, tmp_path):
    data = model.to_json()
    del data["outputs"]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(InputDataError, match="incomplete or damaged"):
        CoatingSurrogate.load(tmp_path / "bad.json")
    (tmp_path / "bad2.json").write_text("{not json")
    with pytest.raises(InputDataError, match="not valid JSON"):
        CoatingSurrogate.load(tmp_path / "bad2.json")


def test_too_few_runs_refused(samples):
    small = SampleSet(samples.runs.head(2), samples.curves, samples.space, {})
    with pytest.raises(InputDataError, match="at least 3"):
        fit_surrogate(small)
