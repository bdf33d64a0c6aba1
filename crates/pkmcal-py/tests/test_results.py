"""Results a scientific user builds on: every result pickles, deep-copies and
compares equal by value after the round trip; a calibration saves whole and
loads back the same; the OptimizeResult-like view (x, jac, fun, cost, status,
covariance over every free parameter) agrees with itself; solver controls
act; deprecated names still work and warn."""

import copy
import pickle
import warnings

import numpy as np
import pytest

import pkmcal
from conftest import EXAMPLES

# Numbers computed twice the same way must agree to rounding.
SAME = 1e-12
# A finite-difference derivative agrees with the exact one to this, relative.
FD_AGREE = 1e-5


def reference_fit(**kw):
    kw.setdefault("frame", "base")
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 30).targets
    c, x = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=3)
    vc, vx = pkmcal.simulate(mech, targets[:8], {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=4)
    return mech, c, x, pkmcal.calibrate(mech, c, x, validation=(vc, vx), kfold=3, **kw)


def tracker_fit():
    """A Gough–Stewart platform with target points, seen from a free
    instrument frame: instrument and frame parameters among the free ones."""
    mech = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
    targets = pkmcal.plan(mech, 25).targets
    pts = mech.target_points
    c, y = pkmcal.simulate(mech, targets, {"b1x": 200.2}, noise=0.005, seed=2, points=pts)
    return mech, pkmcal.calibrate(mech, c, y, points=pts, frame="free")


def round_trips(obj):
    for copied in (pickle.loads(pickle.dumps(obj)), copy.deepcopy(obj), copy.copy(obj)):
        assert type(copied) is type(obj)
        assert copied == obj, f"{type(obj).__name__} changed in a round trip"


def test_every_result_pickles_and_compares_by_value(tmp_path):
    mech, c, x, cal = reference_fit()
    round_trips(cal)
    round_trips(cal.before)
    round_trips(cal.identifiability)
    for w in cal.warnings:
        round_trips(w)
    fig = cal.figures()[0]
    round_trips(fig)
    pred = pkmcal.predict(mech, c, cal, uncertainty=True)
    round_trips(pred)
    round_trips(pkmcal.compensate(mech, pkmcal.plan(mech, 12).targets, cal))
    round_trips(pkmcal.plan(mech, 12))
    round_trips(pkmcal.montecarlo(mech, pkmcal.plan(mech, 12).targets, runs=3, validation=5))
    cal.save(tmp_path / "c.json")
    round_trips(pkmcal.load_calibration(tmp_path / "c.json"))
    # A different result is not equal.
    other = pkmcal.calibrate(mech, c, x, model="rigid", frame="base")
    assert other != cal
    assert pkmcal.predict(mech, c) != pred


def test_a_calibration_back_from_pickle_works_as_the_original():
    mech, c, x, cal = reference_fit()
    back = pickle.loads(pickle.dumps(cal))
    assert back.parameters == cal.parameters
    assert back.std_dev == cal.std_dev
    assert back.mechanism == mech
    assert back.validation[1].distance_rms == cal.validation[1].distance_rms
    assert back.cross_validation["folds"] == 3
    a = pkmcal.predict(mech, c, cal, uncertainty=True)
    b = pkmcal.predict(mech, c, back, uncertainty=True)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.covariance, b.covariance)
    assert back.summary() == cal.summary()
    assert [f.svg for f in back.figures()] == [f.svg for f in cal.figures()]


def test_a_tracker_calibration_pickles_with_its_frame():
    mech, cal = tracker_fit()
    back = pickle.loads(pickle.dumps(cal))
    assert back == cal
    assert back.measurement_parameters == cal.measurement_parameters


def test_save_and_load_give_the_same_calibration(tmp_path):
    mech, c, x, cal = reference_fit()
    cal.save(tmp_path / "cal.json")
    back = pkmcal.Calibration.load(tmp_path / "cal.json")
    assert back == cal
    # The description travels with it: a described mechanism too.
    m2, cal2 = tracker_fit()
    cal2.save(tmp_path / "t.json")
    back2 = pkmcal.Calibration.load(str(tmp_path / "t.json"))
    assert back2 == cal2 and back2.mechanism == m2


def test_a_calibration_of_the_command_line_loads_whole(tmp_path, cli):
    truth = tmp_path / "truth.toml"
    truth.write_text("l11 = 280.3\n")
    data = tmp_path / "m.csv"
    cli("simulate", "--grid", 30, "--truth", truth, "--out", data, "--quiet")
    cli("calibrate", "--data", data, "--out", tmp_path / "p.toml", "--report", tmp_path / "r.json")
    cal = pkmcal.Calibration.load(tmp_path / "r.json")
    saved = pkmcal.load_calibration(tmp_path / "r.json")
    assert cal.parameters == saved.parameters
    assert cal.mechanism == pkmcal.Mechanism()


def test_a_record_without_its_state_is_refused_by_name(tmp_path):
    import json

    mech, c, x, cal = reference_fit()
    cal.save(tmp_path / "cal.json")
    doc = json.loads((tmp_path / "cal.json").read_text())
    del doc["state"]
    (tmp_path / "old.json").write_text(json.dumps(doc))
    with pytest.raises(pkmcal.PkmcalError, match="load_calibration"):
        pkmcal.Calibration.load(tmp_path / "old.json")
    # It still serves predictions.
    assert pkmcal.load_calibration(tmp_path / "old.json").parameters == cal.parameters


def test_non_finite_numbers_survive_the_record(tmp_path):
    # As many readings as free parameters: NaN standard deviations.
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 30).targets
    c, x = pkmcal.simulate(mech, targets, {"l11": 280.3}, noise=0.002, seed=3)
    cal = pkmcal.calibrate(mech, c[:12], x[:12], free=["l11", "l21", "l31", "B2x", "B2y", "B3x"], frame="base")
    cal.save(tmp_path / "c.json")
    back = pkmcal.Calibration.load(tmp_path / "c.json")
    assert back == cal
    assert [np.isnan(v) for v in back.std_dev.values()] == [
        np.isnan(v) for v in cal.std_dev.values()
    ]


def test_mechanisms_compare_by_description():
    assert pkmcal.Mechanism() == pkmcal.Mechanism()
    path = EXAMPLES / "4-rrr" / "mechanism.toml"
    assert pkmcal.Mechanism(path) == pkmcal.Mechanism.from_toml(path.read_text())
    assert pkmcal.Mechanism(path) != pkmcal.Mechanism()


def test_optimize_result_view_is_consistent():
    mech, cal = tracker_fit()
    n = len(cal.free)
    assert cal.x_names == cal.free == cal.covariance_names
    assert cal.x.shape == (n,) and len(cal.x_units) == n
    # The covariance covers every free parameter, frame included.
    assert cal.covariance.shape == (n, n)
    assert any(name.startswith("frame.") for name in cal.free)
    for k, name in enumerate(cal.free):
        value = cal.parameters.get(name, cal.measurement_parameters.get(name))
        assert cal.x[k] == value
        assert abs(np.sqrt(cal.covariance[k, k]) - cal.std_dev[name]) <= SAME * max(
            1.0, cal.std_dev[name]
        )
    corr = cal.correlation
    assert np.allclose(np.diag(corr), 1.0, atol=SAME)
    assert np.allclose(corr, corr.T, atol=SAME)
    assert cal.fun.shape == (cal.jac.shape[0],) and cal.jac.shape[1] == n
    assert abs(cal.cost - 0.5 * np.sum(cal.fun**2)) <= SAME * cal.cost
    assert np.allclose(cal.fun.reshape(cal.residuals.shape), cal.residuals, atol=0)
    assert cal.status in (1, 2, 3, 4, 5) and cal.success and cal.message == cal.termination
    assert cal.nfev >= cal.njev >= 1
    assert "calibration of" in str(cal) and cal.summary() == str(cal)
    assert "--" not in cal.summary()


def test_jac_is_the_derivative_of_fun():
    mech, c, x, cal = reference_fit()
    # Move one free mechanism parameter, refit nothing: the residuals move
    # as the Jacobian says.
    k = cal.free.index("l11")
    h = 1e-6
    p = dict(cal.parameters)
    p["l11"] += h
    moved = pkmcal.predict(mech, c, p).x - x
    base = pkmcal.predict(mech, c, cal.parameters).x - x
    fd = ((moved - base) / h).ravel()
    assert np.allclose(fd, cal.jac[:, k], rtol=FD_AGREE, atol=FD_AGREE)
    assert np.allclose(base.ravel(), cal.fun, atol=1e-9)


def test_solver_controls_act():
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 30).targets
    c, x = pkmcal.simulate(mech, targets, {"l11": 280.3}, noise=0.002, seed=3)
    with pytest.warns(pkmcal.ConvergenceWarning):
        short = pkmcal.calibrate(mech, c, x, max_nfev=2, frame="base")
    assert short.status == 0 and not short.success and short.nfev <= 3
    full = pkmcal.calibrate(mech, c, x, frame="base")
    assert full.success
    # A bound holds the value; its side open with inf.
    bounded = pkmcal.calibrate(mech, c, x, bounds={"l11": (-np.inf, 280.1)}, frame="base")
    assert bounded.success, bounded.message
    assert abs(bounded.parameters["l11"] - 280.1) <= SAME * 280.1
    # x0 as an array over the free mechanism parameters, and as a dict.
    names = [n for n in full.free if n in mech.parameter_names]
    start = [mech.nominal[n] for n in names]
    assert pkmcal.calibrate(mech, c, x, x0=np.array(start), frame="base") == full
    assert pkmcal.calibrate(mech, c, x, x0={"l11": 280.0}, frame="base") == full
    with pytest.raises(pkmcal.PkmcalError, match="one per free mechanism parameter"):
        pkmcal.calibrate(mech, c, x, x0=[1.0, 2.0], frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="ftol"):
        pkmcal.calibrate(mech, c, x, ftol=-1, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="l99"):
        pkmcal.calibrate(mech, c, x, bounds={"l99": (0, 1)}, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="lower bound"):
        pkmcal.calibrate(mech, c, x, bounds={"l11": (281, 280)}, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="either start= or x0="):
        pkmcal.calibrate(mech, c, x, x0={"l11": 280.0}, start={"l11": 280.0}, frame="base")


def test_montecarlo_returns_an_object_and_the_old_keys_warn():
    mech = pkmcal.Mechanism()
    mc = pkmcal.montecarlo(mech, pkmcal.plan(mech, 12).targets, runs=5, validation=5)
    assert isinstance(mc, pkmcal.MonteCarlo)
    assert mc.runs == 5 and mc.parameter_errors.shape == (5, len(mc.parameters))
    assert mc.validation_rms.shape == (5,) and mc.run_converged.dtype == bool
    # An odd number of runs: the median is the middle run's.
    assert mc.validation_rms_median == np.median(mc.validation_rms)
    rms = np.sqrt(np.mean(mc.parameter_errors**2, axis=0))
    assert np.allclose(rms, mc.parameter_rms_error, rtol=SAME, atol=0)
    with pytest.warns(DeprecationWarning, match=r"montecarlo\(\.\.\.\)\.runs"):
        assert mc["runs"] == 5
    with pytest.raises(KeyError):
        mc["nope"]


def test_renamed_mechanism_attributes_warn():
    m = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        names = m.parameter_names
        points = m.target_points
    with pytest.warns(DeprecationWarning, match="parameter_names"):
        assert m.parameters == names
    with pytest.warns(DeprecationWarning, match="target_points"):
        assert np.array_equal(m.targets, points)


def test_a_tolerance_budget_from_python():
    mech = pkmcal.Mechanism()
    tol = {"l11": 0.05, "l12": 0.05, "B2x": 0.1, "dq1": 0.0005, "l31": "0.02%"}
    b = pkmcal.budget(mech, tol, grid=40, samples=3000)
    first, mc = b.first_order["position_rms"], b.monte_carlo["position_rms"]
    assert abs(first - mc) / mc < 0.05
    assert abs(sum(b.shares.values()) - 1) < 1e-12
    assert list(b.shares) == sorted(b.shares, key=b.shares.get, reverse=True)
    assert b.tolerances["l31"] == pytest.approx(0.0002 * mech.nominal["l31"], rel=SAME)
    round_trips(b)
    assert "tolerance budget of" in b.summary()
    plan = pkmcal.plan(mech, 20).targets
    c = pkmcal.budget(mech, tol, grid=40, samples=0, poses=plan)
    assert c.monte_carlo is None
    assert c.after_calibration["position_rms"] < 0.1 * c.first_order["position_rms"]
    assert all(c.sigma_after[n] < c.tolerances[n] for n in tol)
    # The description's [tolerances] table, and a given one replacing it.
    hexapod = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
    h = pkmcal.budget(hexapod, grid=30, samples=0)
    assert len(h.tolerances) == 43
    h2 = pkmcal.budget(hexapod, {"b1x": 0.5}, grid=30, samples=0)
    assert h2.tolerances["b1x"] == 0.5 and max(h2.shares, key=h2.shares.get) == "b1x"
    with pytest.raises(pkmcal.PkmcalError, match="l99"):
        pkmcal.budget(mech, {"l99": 0.1})
    with pytest.raises(pkmcal.PkmcalError, match="0 nominally"):
        pkmcal.budget(mech, {"dq1": "20%"})
    with pytest.raises(pkmcal.PkmcalError, match="no tolerance"):
        pkmcal.budget(mech)


def test_drift_between_calibrations(tmp_path):
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 35).targets

    def fit(l11, seed):
        c, x = pkmcal.simulate(mech, targets, {"l11": l11}, noise=0.002, seed=seed)
        return pkmcal.calibrate(mech, c, x, frame="base")

    a, b, moved = fit(280.3, 1), fit(280.3, 2), fit(280.35, 3)
    same = pkmcal.drift(b, a)
    # One pair of an unchanged machine: no parameter called drifted, and a
    # joint p-value that is not extreme (its false alarms are at their
    # level over many pairs: the library's tests and examples/drift_rate).
    assert same.drifted == [] and same.chi2[2] > 0.01
    changed = pkmcal.drift(moved, a)
    assert changed.drifted[0] == "l11" and changed.joint_drift
    assert changed.parameters[0]["name"] == "l11"
    round_trips(changed)
    assert "Holm–Bonferroni" in changed.summary()
    # At the tool: 50 µm of arm moves the tool beyond the noise at most of
    # the workspace, the unchanged pair at few of its targets.
    w = changed.workspace
    assert w["targets"].shape == (100, 2) and w["change"].shape == (100, 2)
    assert w["beyond"] > 50 and w["distance"][w["largest"]] == w["distance"].max()
    assert same.workspace["beyond"] < 20
    assert pkmcal.drift(moved, a, grid=0).workspace is None
    # Saved records and paths give the same test.
    a.save(tmp_path / "a.json")
    moved.save(tmp_path / "m.json")
    from_files = pkmcal.drift(tmp_path / "m.json", pkmcal.load_calibration(tmp_path / "a.json"))
    assert from_files.drifted == changed.drifted
    assert from_files.chi2 == pytest.approx(changed.chi2, rel=1e-12)
    # Against the nominal values: l11 is 0.3 mm off.
    assert "l11" in pkmcal.drift(a).drifted
    with pytest.raises(pkmcal.PkmcalError, match="mechanism="):
        pkmcal.drift(tmp_path / "a.json")
    hexapod_fit = tracker_fit()[1]
    with pytest.raises(pkmcal.PkmcalError, match="different mechanisms"):
        pkmcal.drift(hexapod_fit, a)
