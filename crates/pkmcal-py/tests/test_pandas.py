"""pandas both ways: a Series read by its labels, DataFrames matched on
their index (or refused, naming both), and every result with a table given
back as a DataFrame. pandas stays optional (these tests need it)."""

import warnings

import numpy as np
import pytest

import pkmcal

pd = pytest.importorskip("pandas")

TRUTH = {"l11": 280.3, "dq3": 0.002}


@pytest.fixture(scope="module")
def frames():
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 35).targets
    c, y = pkmcal.simulate(mech, targets, TRUTH, noise=0.002, seed=1)
    index = pd.Index([f"pose{i}" for i in range(len(c))], name="pose")
    C = pd.DataFrame(c, columns=mech.actuators, index=index)
    X = pd.DataFrame(y, columns=mech.tool_axes, index=index)
    return mech, C, X


def test_a_series_is_read_by_its_labels(frames):
    mech, C, _ = frames
    s = C.iloc[0]
    reversed_ = s[s.index[::-1]]
    assert list(reversed_.index) == ["q3", "q2", "q1"]
    a = pkmcal.predict(mech, s).x
    np.testing.assert_array_equal(pkmcal.predict(mech, reversed_).x, a)
    np.testing.assert_array_equal(a, pkmcal.predict(mech, C.to_numpy()[0]).x)
    # A Series without names (a default index) is read by position.
    np.testing.assert_array_equal(pkmcal.predict(mech, pd.Series(C.to_numpy()[0])).x, a)
    # A label the mechanism lacks is named.
    with pytest.raises(pkmcal.PkmcalError, match="q3"):
        pkmcal.predict(mech, s.rename({"q3": "q9"}))


def test_shuffled_rows_are_aligned_on_the_index_with_a_warning(frames):
    mech, C, X = frames
    plain = pkmcal.calibrate(mech, C, X, frame="base")
    shuffled = C.sample(frac=1, random_state=1)
    with pytest.warns(pkmcal.AlignmentWarning, match="aligned on the index of commands"):
        aligned = pkmcal.calibrate(mech, shuffled, X, frame="base")
    assert aligned.converged
    # The same fit, poses in the shuffled order (the first array's).
    for name, value in plain.parameters.items():
        assert abs(aligned.parameters[name] - value) < 1e-6, name
    # The same rows in the same order: no warning.
    with warnings.catch_warnings():
        warnings.simplefilter("error", pkmcal.AlignmentWarning)
        pkmcal.calibrate(mech, C, X, frame="base")


def test_rows_that_do_not_match_are_refused_naming_both(frames):
    mech, C, X = frames
    with pytest.raises(pkmcal.PkmcalError, match="commands and measured have different rows.*'pose0'"):
        pkmcal.calibrate(mech, C, X.iloc[1:], frame="base")
    other = X.rename(index={"pose3": "elsewhere"})
    with pytest.raises(pkmcal.PkmcalError, match="commands and measured have different rows.*'pose3'"):
        pkmcal.calibrate(mech, C, other, frame="base")
    # A NumPy array beside a DataFrame is taken row for row.
    pkmcal.calibrate(mech, C, X.to_numpy(), frame="base")


def test_results_as_data_frames(frames):
    mech, C, X = frames
    cal = pkmcal.calibrate(mech, C, X, frame="base", tolerances={"l12": 0.05})
    p = cal.to_pandas()
    assert list(p.columns) == ["value", "nominal", "change", "sd", "unit", "free", "tolerance", "from_data", "note"]
    assert p.index.name == "parameter" and p.loc["l11", "value"] == cal.parameters["l11"]
    assert p.loc["l11", "sd"] == cal.std_dev["l11"] and p.loc["dq1", "unit"] == "rad"
    assert p.loc["l12", "tolerance"] == 0.05 and 0 <= p.loc["l12", "from_data"] <= 1
    assert np.isnan(p.loc["k1", "sd"]) and not p.loc["k1", "free"]
    # The table serves as parameters.
    np.testing.assert_array_equal(pkmcal.predict(mech, C, p).x, pkmcal.predict(mech, C, cal).x)

    pred = pkmcal.predict(mech, C, cal)
    df = pred.to_pandas()
    assert list(df.columns[:2]) == ["x", "y"] and df.index.equals(C.index)
    np.testing.assert_array_equal(df[["x", "y"]].to_numpy(), pred.x)
    assert "q_q1" in df.columns and "torque_q3" in df.columns
    assert list(pkmcal.predict(mech, C, cal, outputs="x").to_pandas().columns) == ["x", "y"]

    comp = pkmcal.compensate(mech, X, cal).to_pandas()
    assert list(comp.columns[:3]) == mech.actuators and comp.index.equals(X.index)

    plan = pkmcal.plan(mech, 12, max_candidates=300)
    pp = plan.to_pandas()
    assert list(pp.columns) == mech.tool_axes + mech.actuators and len(pp) == 12
    np.testing.assert_array_equal(pp[mech.tool_axes].to_numpy(), plan.targets)

    mc = pkmcal.montecarlo(mech, plan.targets, runs=5, validation=5).to_pandas()
    assert len(mc) == 5 and {"converged", "validation_rms", "l11"} <= set(mc.columns)

    d = pkmcal.drift(cal).to_pandas()
    assert {"before", "after", "change", "sigma", "z", "p_value", "drifted"} == set(d.columns)
    assert d.index.name == "parameter" and "l11" in d.index

    b = pkmcal.budget(mech, {"l11": 0.01, "D1": "1%"}, samples=0).to_pandas()
    assert list(b.columns) == ["sigma", "unit", "share", "sigma_after"]
    assert abs(b["share"].sum() - 1) < 1e-12
