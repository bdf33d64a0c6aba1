"""The Python package and the command-line tool give the same numbers on the
same data (both call the same library; the tolerance allows only for
rounding)."""

import numpy as np
import pytest

import pkmcal
from conftest import EXAMPLES, columns, read_csv, read_params

# Same library, same data: agreement to rounding.
AGREEMENT = 1e-12


def relative_gap(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)))


def simulated(cli, tmp_path, mechanism, truth, count, noise):
    truth_file = tmp_path / "truth.toml"
    truth_file.write_text("".join(f'"{k}" = {v!r}\n' for k, v in truth.items()))
    data = tmp_path / "data.csv"
    args = ["simulate", "--grid", count, "--noise", noise, "--truth", truth_file, "--out", data, "--quiet"]
    if mechanism is not None:
        args += ["--mechanism", mechanism]
    cli(*args)
    return data


CASES = [
    (None, {"l11": 280.3, "B2y": 0.2, "dq3": 0.002}, 35, 0.002),
    (EXAMPLES / "4-rrr" / "mechanism.toml", {}, 40, 0.002),
    (EXAMPLES / "gough-stewart-6" / "mechanism.toml", {}, 40, 0.002),
]


@pytest.mark.parametrize("mechanism,truth,count,noise", CASES, ids=["reference", "4-rrr", "gough-stewart-6"])
def test_calibration_equals_cli(cli, tmp_path, mechanism, truth, count, noise):
    mech = pkmcal.Mechanism(mechanism)
    if not truth:
        # A perturbation of the first free length and the first offset.
        names = mech.default_free
        units = mech.parameter_units
        a, b = names[0], names[-1]
        step = {"mm": 0.2, "rad": 0.001}
        truth = {a: mech.nominal[a] + step[units[a]], b: mech.nominal[b] + step[units[b]]}
    data = simulated(cli, tmp_path, mechanism, truth, count, noise)
    out = tmp_path / "identified.toml"
    args = ["calibrate", "--data", data, "--out", out, "--quiet"]
    if mechanism is not None:
        args += ["--mechanism", mechanism]
    cli(*args)
    expected = read_params(out)

    table = read_csv(data)
    commands = columns(table, mech.actuators)
    measured = columns(table, mech.tool_axes)
    cal = pkmcal.calibrate(mech, commands, measured, frame="base")
    got = cal.parameters
    assert set(got) == set(expected)
    for name, value in expected.items():
        assert relative_gap(got[name], value) < AGREEMENT, name
    # The identified truth is recovered within a few standard deviations
    # (without the mechanism's tolerances, which this truth exceeds tenfold:
    # the priors rightly pull it towards nominal, with a warning).
    free = pkmcal.calibrate(mech, commands, measured, tolerances=False, frame="base") if cal.priors else cal
    for name, value in truth.items():
        assert abs(free.parameters[name] - value) < 6 * free.std_dev[name] + 1e-9, name
    assert cal.converged
    assert cal.after.distance_rms < cal.before.distance_rms


@pytest.mark.parametrize("mechanism", [None, EXAMPLES / "gough-stewart-8" / "mechanism.toml"], ids=["reference", "gough-stewart-8"])
def test_predict_equals_cli(cli, tmp_path, mechanism):
    mech = pkmcal.Mechanism(mechanism)
    targets = pkmcal.plan(mech, 12, max_candidates=300).targets
    commands = pkmcal.nominal_commands(mech, targets)
    path = tmp_path / "commands.csv"
    path.write_text(
        ",".join(mech.actuators) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in commands) + "\n"
    )
    out = tmp_path / "predicted.csv"
    args = ["predict", "--commands", path, "--out", out, "--quiet"]
    if mechanism is not None:
        args += ["--mechanism", mechanism]
    cli(*args)
    table = read_csv(out)
    expected = columns(table, mech.tool_axes)
    got = pkmcal.predict(mech, commands).x
    assert relative_gap(got, expected) < AGREEMENT
    # The nominal commands of a target reach it.
    assert np.max(np.abs(got - targets)) < 1e-8


def test_compensate_equals_cli(cli, tmp_path):
    mech = pkmcal.Mechanism()
    truth = {"l11": 280.3, "dq2": -0.001}
    params = tmp_path / "p.toml"
    params.write_text("".join(f"{k} = {v!r}\n" for k, v in truth.items()))
    targets = pkmcal.plan(mech, 10).targets
    tfile = tmp_path / "targets.csv"
    tfile.write_text("target_x,target_y\n" + "\n".join(f"{float(x)!r},{float(y)!r}" for x, y in targets) + "\n")
    out = tmp_path / "commands.csv"
    cli("compensate", "--params", params, "--targets", tfile, "--out", out)
    table = read_csv(out)
    comp = pkmcal.compensate(mech, targets, truth)
    assert relative_gap(comp.commands, columns(table, mech.actuators)) < AGREEMENT
    assert relative_gap(comp.correction, columns(table, [f"delta_{a}" for a in mech.actuators])) < AGREEMENT
    # The compensated commands reach the targets on the calibrated machine.
    reached = pkmcal.predict(mech, comp.commands, truth).x
    assert np.max(np.abs(reached - targets)) < 1e-8


def test_plan_equals_cli(cli, tmp_path):
    out = tmp_path / "plan.csv"
    cli("plan", "--count", 20, "--out", out, "--quiet")
    table = read_csv(out)
    p = pkmcal.plan(pkmcal.Mechanism(), 20)
    assert relative_gap(p.targets, columns(table, ["target_x", "target_y"])) < AGREEMENT
    assert relative_gap(p.commands, columns(table, ["q1", "q2", "q3"])) < AGREEMENT
    assert p.condition < p.grid_condition
