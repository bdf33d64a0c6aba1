"""Tolerances as priors: the maximum a posteriori fit equals an independent
one (scipy's least_squares with the prior rows appended), the mechanism's
[tolerances] table applies unless turned off, and answers far from what
was known are warned about."""

import warnings

import numpy as np
import pytest
from scipy.optimize import least_squares

import pkmcal
from conftest import EXAMPLES

# The agreement with an independent MAP fit.
SAME_MM = 1e-6
SAME_RAD = 1e-8
# A stiffness agrees to this share of its tolerance (scipy's finite
# differences settle it no closer).
SAME_SHARE_OF_TOLERANCE = 1e-4


def test_map_equals_scipy_with_the_prior_rows_appended():
    m = pkmcal.Mechanism()
    truth = dict(m.nominal)
    truth["l11"] += 0.03
    truth["l21"] -= 0.04
    truth["dq2"] += 0.002
    targets = pkmcal.plan(m, 20, max_candidates=400).targets
    commands, measured = pkmcal.simulate(m, targets, truth, noise=0.002, seed=5)
    sigma = 0.002
    tolerances = {"l11": 0.05, "l21": 0.05, "k2": "20%", "dq1": 0.001}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", pkmcal.PkmcalWarning)
        cal = pkmcal.calibrate(m, commands, measured, sigma=sigma, tolerances=tolerances, frame="base")
    names = cal.x_names
    # A tolerance frees its parameter: k2 is not in the default set.
    assert "k2" in names and "k2" not in pkmcal.analyze(m, commands, measured, frame="base").free
    prior = {p["name"]: (p["centre"], p["sigma"]) for p in cal.priors}
    assert prior["k2"] == (m.nominal["k2"], 0.2 * m.nominal["k2"])
    nominal = m.nominal

    def residuals(x: np.ndarray) -> np.ndarray:
        p = dict(nominal)
        p.update(zip(names, x))
        r = ((pkmcal.predict(m, commands, p).x - measured) / sigma).ravel()
        rows = [(x[i] - prior[n][0]) / prior[n][1] for i, n in enumerate(names) if n in prior]
        return np.concatenate([r, rows])

    x0 = np.array([nominal[n] for n in names])
    ref = least_squares(residuals, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, x_scale="jac")
    assert ref.status > 0
    for n, unit, a, b in zip(names, cal.x_units, cal.x, ref.x):
        if unit == "mm":
            assert abs(a - b) < SAME_MM, (n, a, b)
        elif unit == "rad":
            assert abs(a - b) < SAME_RAD, (n, a, b)
        else:
            # A stiffness (N·m/rad): to a share of its tolerance.
            assert abs(a - b) < SAME_SHARE_OF_TOLERANCE * prior[n][1], (n, a, b)
    # pkmcal's point is at least as low.
    ours = np.sum(residuals(cal.x) ** 2)
    assert ours <= 2 * ref.cost * (1 + 1e-9)
    # The readings' residuals alone in fun; the priors' follow from priors.
    assert cal.fun.shape == (measured.size,)


def test_the_mechanism_s_table_applies_unless_turned_off():
    path = EXAMPLES / "gough-stewart-6" / "mechanism.toml"
    m = pkmcal.Mechanism(path)
    targets = pkmcal.plan(m, 30, max_candidates=300).targets
    commands, measured = pkmcal.simulate(m, targets, None, noise=0.005, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", pkmcal.PkmcalWarning)
        with_table = pkmcal.calibrate(m, commands, measured, frame="base")
        off = pkmcal.calibrate(m, commands, measured, tolerances=False, frame="base")
        one = pkmcal.calibrate(m, commands, measured, tolerances={"a1x": 0.01}, frame="base")
    assert len(with_table.priors) == 43
    assert off.priors == [] and off.from_data == {}
    sigma = {p["name"]: p["sigma"] for p in one.priors}
    assert sigma["a1x"] == 0.01 and sigma["a1y"] == 0.05 and len(sigma) == 43
    assert set(with_table.from_data) == {p["name"] for p in with_table.priors if p["name"] in with_table.free}


def test_a_value_far_outside_its_tolerance_is_a_tolerance_warning():
    m = pkmcal.Mechanism()
    truth = dict(m.nominal)
    truth["l11"] += 0.5
    targets = pkmcal.plan(m, 25, max_candidates=400).targets
    commands, measured = pkmcal.simulate(m, targets, truth, noise=0.002, seed=1)
    with pytest.warns(pkmcal.ToleranceWarning, match="l11"):
        cal = pkmcal.calibrate(m, commands, measured, tolerances={"l11": 0.05}, frame="base")
    assert any(w.kind == "beyond_tolerance" for w in cal.warnings)


def test_bad_tolerances_are_refused_by_name():
    m = pkmcal.Mechanism()
    c, x = pkmcal.simulate(m, pkmcal.plan(m, 12, max_candidates=200).targets, seed=1)
    with pytest.raises(pkmcal.PkmcalError, match="l111"):
        pkmcal.calibrate(m, c, x, tolerances={"l111": 0.1}, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="tolerance"):
        pkmcal.calibrate(m, c, x, tolerances={"l11": -1}, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="0 nominally"):
        pkmcal.calibrate(m, c, x, tolerances={"dq1": "10%"}, frame="base")


def test_analyze_plan_and_montecarlo_take_the_priors():
    m = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
    plan = pkmcal.plan(m, 30, max_candidates=300)
    bare = pkmcal.plan(m, 30, max_candidates=300, tolerances=False)
    assert plan.observability != bare.observability
    commands, measured = pkmcal.simulate(m, plan.targets, None, noise=0.005, seed=3)
    a = pkmcal.analyze(m, commands, measured, frame="base")
    assert a.held == ["1.000·kL1"] and a.unidentifiable == []
    assert pkmcal.analyze(m, commands, measured, tolerances=False, frame="base").held == []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", pkmcal.PkmcalWarning)
        mc = pkmcal.montecarlo(m, plan.targets, runs=4, validation=10)
        off = pkmcal.montecarlo(m, plan.targets, runs=4, validation=10, tolerances=False)
    assert "kL1" in mc.parameters and "kL1" not in off.parameters


def test_a_stated_noise_the_residuals_exceed_is_a_model_warning():
    m = pkmcal.Mechanism(EXAMPLES / "linear-delta" / "mechanism.toml")
    truth = dict(m.nominal)
    for k, t in enumerate(["a.tilt1", "a.tilt2", "b.tilt1", "b.tilt2", "c.tilt1", "c.tilt2"]):
        truth[t] += 0.002 if k % 2 == 0 else -0.0014
    targets = pkmcal.plan(m, 40, max_candidates=400).targets
    commands, measured = pkmcal.simulate(m, targets, truth, noise=0.002, seed=4)
    with pytest.warns(pkmcal.ModelWarning, match="tilt"):
        cal = pkmcal.calibrate(m, commands, measured, stated_noise=0.002, frame="base")
    (w,) = [w for w in cal.warnings if w.kind == "model_inadequate"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", pkmcal.ModelWarning)
        pkmcal.calibrate(m, commands, measured, stated_noise=0.05, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="stated_angle_noise"):
        pkmcal.calibrate(m, commands, measured, stated_angle_noise=1e-5, frame="base")


def test_a_stated_distance_noise_is_the_calipers_prior_and_reference():
    """stated_distance_noise= is to distances= what stated_noise= is to the
    readings: caliper distances far noisier than stated are a model warning
    naming the distances; a fair statement is not; without distances it is
    refused."""
    delta = pkmcal.Mechanism(EXAMPLES / "linear-delta" / "mechanism.toml")
    targets = pkmcal.plan(delta, 24).targets
    commands, measured = pkmcal.simulate(delta, targets, axes=["probe"], noise=0.005, seed=1)
    a, b = targets[:12], targets[12:]
    ca, xa = pkmcal.simulate(delta, a, seed=2)
    cb, xb = pkmcal.simulate(delta, b, seed=3)
    d = np.linalg.norm(xa - xb, axis=1) + np.random.default_rng(4).normal(0.0, 0.02, 12)
    free = ["delta_radius", "angle_a", "angle_b", "da", "db", "dc", "arm_a", "arm_b", "arm_c"]
    fit = lambda **kw: pkmcal.calibrate(  # noqa: E731
        delta, commands, measured, axes=["probe"], free=free, distances=(ca, cb, d), **kw
    )
    with pytest.warns(pkmcal.ModelWarning, match=r"\(distance readings\) exceeds the stated 1.000e-3 mm"):
        fit(stated_distance_noise=0.001)
    with warnings.catch_warnings():
        warnings.simplefilter("error", pkmcal.ModelWarning)
        fit(stated_distance_noise=0.02)
    with pytest.raises(pkmcal.PkmcalError, match="give the distances too"):
        pkmcal.calibrate(delta, commands, measured, axes=["probe"], stated_distance_noise=0.02)
    with pytest.raises(pkmcal.PkmcalError, match="stated_distance_noise: NaN mm must be between"):
        fit(stated_distance_noise=float("nan"))
    with pytest.raises(pkmcal.PkmcalError, match="stated_relative= needs stated_noise="):
        fit(stated_relative=True)
    # Only the ratio stated: the scale comes from the residuals, untested.
    with warnings.catch_warnings():
        warnings.simplefilter("error", pkmcal.ModelWarning)
        fit(stated_noise=0.0001, stated_distance_noise=0.0004, stated_relative=True)
