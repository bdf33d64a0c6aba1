"""Bad input gives a PkmcalError (a ValueError) that says what is wrong and,
at a pose, which row; never a crash."""

import numpy as np
import pytest

import pkmcal
from conftest import EXAMPLES


@pytest.fixture(scope="module")
def ref():
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 20).targets
    commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.2}, noise=0.002, seed=1)
    return mech, commands, measured


def test_wrong_shapes(ref):
    mech, c, y = ref
    with pytest.raises(pkmcal.PkmcalError, match=r"measured: expected shape \(n, 2\) with columns x, y, got \(20, 1\)"):
        pkmcal.calibrate(mech, c, y[:, :1], frame="base")
    with pytest.raises(pkmcal.PkmcalError, match=r"commands: expected shape \(n, 3\).*got \(20, 2\)"):
        pkmcal.predict(mech, c[:, :2])
    with pytest.raises(pkmcal.PkmcalError, match="20 rows and measured 19"):
        pkmcal.calibrate(mech, c, y[:19], frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="expected an array of numbers"):
        pkmcal.predict(mech, [["a", "b", "c"]])
    with pytest.raises(pkmcal.PkmcalError, match="no rows"):
        pkmcal.predict(mech, np.zeros((0, 3)))


def test_nan_names_the_row(ref):
    mech, c, y = ref
    bad = y.copy()
    bad[7, 1] = np.nan
    with pytest.raises(pkmcal.PkmcalError) as e:
        pkmcal.calibrate(mech, c, bad, frame="base")
    assert e.value.pose == 7
    assert "row 7, column 1 (y) is NaN" in str(e.value)
    assert isinstance(e.value, ValueError)


def test_unknown_parameter_names(ref):
    mech, c, y = ref
    with pytest.raises(pkmcal.PkmcalError, match="unknown parameter `l99`"):
        pkmcal.predict(mech, c, {"l99": 1.0})
    with pytest.raises(pkmcal.PkmcalError, match="free: unknown parameter `bogus`"):
        pkmcal.calibrate(mech, c, y, free=["l11", "bogus"], frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="fix: unknown parameter"):
        pkmcal.calibrate(mech, c, y, fix="nope", frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="`l11` must be a number"):
        pkmcal.predict(mech, c, {"l11": "long"})


def test_values_that_cannot_describe_the_mechanism(ref):
    mech, c, _ = ref
    with pytest.raises(pkmcal.PkmcalError, match="cannot describe this mechanism"):
        pkmcal.predict(mech, c, {"l11": -5.0})


def test_unreachable_target_names_the_row(ref):
    mech, _, _ = ref
    targets = np.array([[0.0, 200.0], [5000.0, 0.0]])
    with pytest.raises(pkmcal.PkmcalError) as e:
        pkmcal.compensate(mech, targets)
    assert e.value.pose == 1
    assert "pose 1" in str(e.value)


def test_options(ref):
    mech, c, y = ref
    with pytest.raises(pkmcal.PkmcalError, match="unknown model"):
        pkmcal.calibrate(mech, c, y, model="elastic", frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="loss: unknown"):
        pkmcal.calibrate(mech, c, y, loss="l1", frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="frame: unknown"):
        pkmcal.calibrate(mech, c, y, frame="tracker")
    with pytest.raises(pkmcal.PkmcalError, match="either validation"):
        pkmcal.calibrate(mech, c, y, validation=(c, y), holdout=0.2, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="load: needs 2 values"):
        pkmcal.predict(mech, c, load=[1.0, 2.0, 3.0])
    # force= is the old name of load=, still read; not both.
    with pytest.raises(pkmcal.PkmcalError, match="load: needs 2 values"):
        pkmcal.predict(mech, c, force=[1.0, 2.0, 3.0])
    with pytest.raises(pkmcal.PkmcalError, match="once"):
        pkmcal.predict(mech, c, load=[1.0, 2.0], force=[1.0, 2.0])
    # A load no machine works under (a unit slip) is named as the load.
    with pytest.raises(pkmcal.PkmcalError, match="load: the tool load"):
        pkmcal.predict(mech, c, load=[1e9, 1e9])
    assert np.array_equal(
        pkmcal.predict(mech, c, load=[1.0, 2.0]).x, pkmcal.predict(mech, c, force=[1.0, 2.0]).x
    )
    with pytest.raises(pkmcal.PkmcalError, match="uncertainty=True needs"):
        pkmcal.predict(mech, c, uncertainty=True)
    with pytest.raises(pkmcal.PkmcalError, match="one number cannot be the σ"):
        # tool axes x, y share mm on the reference; a platform mixes mm and rad.
        gs = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
        t = pkmcal.plan(gs, 10, max_candidates=200).targets
        gc, gy = pkmcal.simulate(gs, t, seed=1)
        pkmcal.calibrate(gs, gc, gy, sigma=0.01, frame="base")


def test_mechanism_sources(tmp_path):
    with pytest.raises(FileNotFoundError, match="cannot read mechanism file .*missing.toml") as e:
        pkmcal.Mechanism("missing.toml")
    assert isinstance(e.value, pkmcal.PkmcalError) and e.value.filename == "missing.toml"
    with pytest.raises(pkmcal.PkmcalError, match="needs `type"):
        pkmcal.Mechanism("name = 'no type'\n")
    with pytest.raises(pkmcal.PkmcalError, match="unknown mechanism type `hexapod`"):
        pkmcal.Mechanism({"type": "hexapod"})
    with pytest.raises(pkmcal.PkmcalError, match="cannot hold"):
        pkmcal.Mechanism({"type": "planar", "x": object()})
    with pytest.raises(pkmcal.PkmcalError, match="expected None, a path"):
        pkmcal.Mechanism(42)


def test_calibration_of_another_mechanism(ref):
    mech, c, y = ref
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    other = pkmcal.Mechanism(EXAMPLES / "4-rrr" / "mechanism.toml")
    with pytest.raises(pkmcal.PkmcalError, match="another mechanism"):
        pkmcal.predict(other, np.zeros((1, len(other.actuators))), cal)


def test_no_half_written_figure(tmp_path, ref):
    mech, c, y = ref
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    with pytest.raises(pkmcal.PkmcalError):
        cal.figures()[0].save(tmp_path / "no-such-dir" / "errors.svg")
    assert not (tmp_path / "no-such-dir").exists()


def test_unreachable_targets_can_be_skipped(ref):
    mech, _, _ = ref
    targets = np.array([[0.0, 200.0], [5000.0, 0.0], [10.0, 190.0]])
    comp = pkmcal.compensate(mech, targets, skip_unreachable=True)
    assert comp.skipped == [1]
    assert np.all(np.isnan(comp.commands[1])) and np.all(np.isfinite(comp.commands[[0, 2]]))


def test_ball_bar_sockets():
    with pytest.raises(pkmcal.PkmcalError, match=r"sockets: expected shape \(k, 2\) or \(k, 3\).*got \(3,\)"):
        pkmcal.trilaterate([1.0, 2.0, 3.0], [[1.0, 2.0, 3.0]])
    mech = pkmcal.Mechanism()
    with pytest.raises(pkmcal.PkmcalError, match="ballbar: the dict needs"):
        pkmcal.simulate(mech, [[0.0, 200.0]], ballbar={"bar_offset": 1.0})
    with pytest.raises(pkmcal.PkmcalError, match=r'ballbar: "sockets": expected shape'):
        pkmcal.simulate(mech, [[0.0, 200.0]], ballbar={"sockets": [[1.0, 2.0, 3.0, 4.0]]})


def test_commands_that_do_not_assemble_can_be_skipped(ref):
    mech, _, _ = ref
    good = pkmcal.nominal_commands(mech, [[0.0, 200.0], [10.0, 190.0]])
    commands = np.array([good[0], [5.0, 5.0, 5.0], good[1]])
    with pytest.raises(pkmcal.PkmcalError, match="pose 1"):
        pkmcal.predict(mech, commands)
    pred = pkmcal.predict(mech, commands, skip_unreachable=True)
    assert pred.skipped == [1]
    assert np.all(np.isnan(pred.x[1])) and np.all(np.isfinite(pred.x[[0, 2]]))
    np.testing.assert_allclose(pred.x[[0, 2]], [[0.0, 200.0], [10.0, 190.0]], atol=1e-9)


def test_the_readme_compensated_plan_predicts_back():
    # The README's example: plan, simulate a machine with l11 = 280.3 and
    # dq3 = 0.002, calibrate, compensate the planned targets; predicting
    # those commands under the calibration returns the targets (eight of the
    # planned poses lie where forward kinematics from the reference
    # configuration alone crosses a singularity).
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 35).targets
    commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=1)
    cal = pkmcal.calibrate(mech, commands, measured, frame="base")
    comp = pkmcal.compensate(mech, targets, cal)
    back = pkmcal.predict(mech, comp.commands, cal)
    np.testing.assert_allclose(back.x, targets, atol=1e-9)
    c = pkmcal.nominal_commands(mech, [[232.0, 102.0]])
    pkmcal.predict(mech, c + [0.0, -5e-4, 0.0])


def test_python_shapes_of_arguments_are_accepted_or_refused_in_python_words(tmp_path):
    import pathlib

    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 20).targets
    commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.1}, noise=0.001, seed=1)
    # Parameters as any mapping, or a pathlib.Path to a parameter file.
    class Values(dict):
        pass

    a = pkmcal.predict(mech, commands, {"l11": 280.1}).x
    np.testing.assert_array_equal(pkmcal.predict(mech, commands, Values(l11=280.1)).x, a)
    f = tmp_path / "p.toml"
    f.write_text("l11 = 280.1\n")
    np.testing.assert_array_equal(pkmcal.predict(mech, commands, pathlib.Path(f)).x, a)
    with pytest.raises(TypeError, match="params: expected .* got int"):
        pkmcal.predict(mech, commands, 3)
    # Validation as a list as well as a tuple.
    v = [commands[:5], measured[:5]]
    assert pkmcal.calibrate(mech, commands, measured, validation=v, frame="base").validation is not None
    # A figure is SVG or PNG, never SVG text in a .pdf.
    fig = pkmcal.calibrate(mech, commands, measured, frame="base").figures()[0]
    with pytest.raises(pkmcal.PkmcalError, match=r"\.svg or \.png"):
        fig.save(tmp_path / "f.pdf")
    assert not (tmp_path / "f.pdf").exists()
    # A misspelled ballbar key is refused, naming the right one.
    with pytest.raises(pkmcal.PkmcalError, match='did you mean "bar_offset"'):
        pkmcal.simulate(mech, targets, ballbar={"sockets": [[0, 0], [100, 0], [0, 100]], "bar_ofset": 1.0})


def test_standard_deviations_are_bounded_by_the_library(ref):
    """σ and distances are bounded once, in the library, which names the pose."""
    mech, c, y = ref
    for s in (-1.0, 0.0, np.inf):
        with pytest.raises(pkmcal.PkmcalError, match="standard deviation .* must be a finite number") as e:
            pkmcal.calibrate(mech, c, y, sigma=s, frame="base")
        assert e.value.pose == 0
    with pytest.raises(pkmcal.PkmcalError, match="distance 1: measured `distance` = inf") as e:
        pkmcal.calibrate(mech, c, y, frame="base", distances=(c[:3], c[3:6], [1.0, np.inf, 2.0]))
    assert e.value.pose == 1
    with pytest.raises(pkmcal.PkmcalError, match="distance 1: standard deviation -1.0 mm"):
        pkmcal.calibrate(mech, c, y, frame="base", distances=(c[:3], c[3:6], [1.0, 1.0, 2.0], [1.0, -1.0, 1.0]))
