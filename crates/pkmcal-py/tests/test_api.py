"""The package in a user's hands: mechanisms from files, text and dicts,
NumPy conventions, the result object, figures, the GIL."""

import pathlib
import threading
import tomllib

import numpy as np
import pytest

import pkmcal
from conftest import EXAMPLES

# Numbers computed twice the same way must agree to rounding.
SAME = 1e-12


def test_mechanism_from_file_text_and_dict_agree():
    path = EXAMPLES / "4-rrr" / "mechanism.toml"
    text = path.read_text()
    with open(path, "rb") as f:
        as_dict = tomllib.load(f)
    a = pkmcal.Mechanism(path)
    b = pkmcal.Mechanism.from_toml(text)
    c = pkmcal.Mechanism(as_dict)
    d = pkmcal.Mechanism(str(path))
    assert a.kind == "planar" and a.dof == 3
    targets = pkmcal.plan(a, 12, max_candidates=300).targets
    commands = pkmcal.nominal_commands(a, targets)
    x = [pkmcal.predict(m, commands).x for m in (a, b, c, d)]
    for other in x[1:]:
        assert np.max(np.abs(other - x[0])) < SAME
    assert a.nominal == c.nominal


def test_mechanism_properties():
    m = pkmcal.Mechanism()
    assert m.actuators == ["q1", "q2", "q3"]
    assert m.tool_axes == ["x", "y"] and m.tool_units == ["mm", "mm"]
    assert m.parameter_units["l11"] == "mm" and m.parameter_units["dq1"] == "rad"
    assert m.parameter_kinds["k1"] == "stiffness"
    assert m.workspace.shape == (2, 2)
    assert "2 DOF" in repr(m)
    gs = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
    assert gs.tool_units == ["mm", "mm", "mm", "rad", "rad", "rad"]


def test_one_row_in_one_row_out():
    m = pkmcal.Mechanism()
    c = pkmcal.nominal_commands(m, [0.0, 200.0])
    assert c.shape == (3,)
    p = pkmcal.predict(m, c)
    assert p.x.shape == (2,) and p.torque.shape == (3,)
    assert np.allclose(p.x, [0.0, 200.0], atol=1e-8)
    # Lists, integers and non-contiguous views are read too.
    many = pkmcal.nominal_commands(m, np.array([[0, 200], [10, 190]])[:, :])
    assert pkmcal.predict(m, many.T.copy().T).x.shape == (2, 2)
    assert np.array_equal(pkmcal.predict(m, many.tolist()).x, pkmcal.predict(m, many).x)


def test_calibration_result():
    m = pkmcal.Mechanism()
    targets = pkmcal.plan(m, 35).targets
    truth = {"l11": 280.3, "dq3": 0.002}
    c, y = pkmcal.simulate(m, targets, truth, noise=0.002, seed=3)
    vc, vy = pkmcal.simulate(m, pkmcal.plan(m, 12, spacing=9.0).targets, truth, noise=0.002, seed=4)
    cal = pkmcal.calibrate(m, c, y, validation=(vc, vy), kfold=4, frame="base")
    assert cal.converged and cal.model == "exact"
    assert set(cal.free) == set(m.default_free)
    assert abs(cal.parameters["l11"] - 280.3) < 6 * cal.std_dev["l11"]
    assert cal.units["dq3"] == "rad"
    cov = cal.covariance
    names = cal.covariance_names
    assert cov.shape == (len(names), len(names))
    assert np.allclose(cov, cov.T)
    i = names.index("l11")
    assert abs(np.sqrt(cov[i, i]) - cal.std_dev["l11"]) < 1e-12
    ident = cal.identifiability
    assert ident.rank == len(cal.free) and ident.singular_values[0] > 0
    assert cal.residuals.shape == (35, 2)
    before, after = cal.validation
    assert after.distance_rms < before.distance_rms
    assert cal.cross_validation["folds"] == 4
    assert cal.after.distance_max < 0.02 < cal.before.distance_max
    html = cal._repr_html_()
    assert "<table>" in html and "l11" in html and "dq3" in html
    text = cal.to_toml()
    assert tomllib.loads(text)["l11"] == cal.parameters["l11"]
    # The identified parameters feed prediction with uncertainty.
    p = pkmcal.predict(m, c, cal, uncertainty=True)
    assert p.covariance.shape == (35, 2, 2)
    assert np.all(np.diagonal(p.covariance, axis1=1, axis2=2) > 0)


def test_unidentifiable_parameters_are_named():
    m = pkmcal.Mechanism()
    c, y = pkmcal.simulate(m, pkmcal.plan(m, 20).targets, seed=1)
    ident = pkmcal.analyze(m, c, y, free="all", frame="base")
    # Without a load the stiffnesses do not show: three directions are lost.
    assert ident.rank == len(ident.singular_values) - 3
    assert len(ident.unidentifiable) == 3
    assert sorted(u["fixed"] for u in ident.unidentifiable) == ["k1", "k2", "k3"]
    assert all(list(u["terms"]) == [u["fixed"]] for u in ident.unidentifiable)
    cal = pkmcal.calibrate(m, c, y, free="all", frame="base")
    assert any(w.kind in ("unidentifiable", "stiffness_ratios") for w in cal.warnings)


def test_instruments():
    gs = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
    t = pkmcal.plan(gs, 30, max_candidates=400).targets
    c, y = pkmcal.simulate(gs, t, noise=0.001, seed=1)
    z = pkmcal.simulate(gs, t, axes=["z"], seed=1)[1]
    assert z.shape == (30, 1) and np.allclose(z[:, 0], y[:, 2])
    ref = pkmcal.Mechanism()
    sockets = np.array([[-300.0, 0.0], [300.0, 0.0], [0.0, -50.0]])
    rc, d = pkmcal.simulate(ref, pkmcal.plan(ref, 25).targets, {"l11": 280.2}, ballbar={"sockets": sockets}, seed=1)
    cal = pkmcal.calibrate(ref, rc, d, ballbar={"sockets": sockets})
    assert cal.axes == ["d1", "d2", "d3"]
    assert abs(cal.parameters["l11"] - 280.2) < 1e-6
    x, cov = pkmcal.trilaterate(sockets, d)
    reached = pkmcal.predict(ref, rc, {"l11": 280.2}).x
    assert np.max(np.abs(x - reached)) < 1e-6 and cov.shape == (25, 2, 2)


def test_figures_render(tmp_path):
    m = pkmcal.Mechanism()
    c, y = pkmcal.simulate(m, pkmcal.plan(m, 20).targets, {"l11": 280.2}, noise=0.002, seed=1)
    cal = pkmcal.calibrate(m, c, y, frame="base")
    figs = cal.figures()
    assert [f.name for f in figs][:2] == ["errors", "parameters"]
    for f in figs:
        assert f._repr_svg_().lstrip().startswith("<svg")
        assert f.png[:8] == b"\x89PNG\r\n\x1a\n"
    figs[0].save(tmp_path / "errors.png")
    assert (tmp_path / "errors.png").read_bytes()[:4] == b"\x89PNG"
    cal.save_report(tmp_path / "report")
    assert "<html" in (tmp_path / "report" / "report.html").read_text()


def test_the_gil_is_released_during_long_computations():
    m = pkmcal.Mechanism()
    targets = pkmcal.plan(m, 35).targets
    done = threading.Event()
    ticks = 0

    def work():
        pkmcal.montecarlo(m, targets, runs=60)
        done.set()

    t = threading.Thread(target=work)
    t.start()
    while not done.is_set():
        ticks += 1
    t.join()
    # With the GIL held, this thread could not run until the study ended.
    assert ticks > 1000


def test_help_explains():
    assert "mm" in pkmcal.calibrate.__doc__ and "free" in pkmcal.calibrate.__doc__
    assert pkmcal.Mechanism.__doc__
    import inspect

    sig = inspect.signature(pkmcal.calibrate).parameters
    assert "sigma" in sig and sig["frame"].default == "auto" and sig["seed"].default == 1


def test_mechanisms_pickle():
    import pickle

    for m in (pkmcal.Mechanism(), pkmcal.Mechanism(EXAMPLES / "five-bar" / "mechanism.toml")):
        back = pickle.loads(pickle.dumps(m))
        assert back.nominal == m.nominal and back.actuators == m.actuators
        c = pkmcal.nominal_commands(m, pkmcal.plan(m, 10, max_candidates=300).targets)
        assert np.array_equal(pkmcal.predict(back, c).x, pkmcal.predict(m, c).x)


def test_spatial_delta_and_probe_heights():
    """A spatial description (the linear delta) from Python, calibrated from
    heights probed on a tilted bed (axes=["probe"]); the CLI reads the same
    kind of file."""
    delta = pkmcal.Mechanism(EXAMPLES / "linear-delta" / "mechanism.toml")
    assert delta.kind == "spatial"
    assert delta.tool_axes == ["x", "y", "z"]
    plan = pkmcal.plan(delta, 25)
    truth = {"delta_radius": 130.4, "angle_a": 3.668, "da": 0.3, "db": -0.2}
    commands, measured = pkmcal.simulate(delta, plan.targets, truth, axes=["probe"], seed=1)
    assert measured.shape == (25, 1)
    cal = pkmcal.calibrate(
        delta,
        commands,
        measured,
        axes=["probe"],
        free=["delta_radius", "angle_a", "angle_b", "da", "db", "dc"], frame="base",
    )
    assert abs(cal.parameters["delta_radius"] - 130.4) < 1e-6
    assert abs(cal.parameters["da"] - 0.3) < 1e-6
    with pytest.raises(pkmcal.PkmcalError, match="bed plane"):
        pkmcal.calibrate(delta, commands, measured, axes=["probe"], frame="free")


def test_distances_between_poses_with_probe_heights():
    """Caliper distances between pairs of poses fitted with probe heights
    (distances=): the arm lengths come back, and the distance errors are
    reported before and after."""
    delta = pkmcal.Mechanism(EXAMPLES / "linear-delta" / "mechanism.toml")
    truth = {"delta_radius": 130.4, "da": 0.3, "arm_a": 250.5, "arm_b": 249.6}
    targets = pkmcal.plan(delta, 24).targets
    commands, measured = pkmcal.simulate(delta, targets, truth, axes=["probe"], seed=1)
    a, b = targets[:12], targets[12:]
    ca, xa = pkmcal.simulate(delta, a, truth, seed=1)
    cb, xb = pkmcal.simulate(delta, b, truth, seed=1)
    d = np.linalg.norm(xa - xb, axis=1)
    free = ["delta_radius", "angle_a", "angle_b", "da", "db", "dc", "arm_a", "arm_b", "arm_c"]
    cal = pkmcal.calibrate(
        delta, commands, measured, axes=["probe"], free=free, distances=(ca, cb, d)
    )
    assert abs(cal.parameters["arm_a"] - 250.5) < 1e-6
    assert abs(cal.parameters["arm_b"] - 249.6) < 1e-6
    dist = cal.distances
    assert dist["count"] == 12 and dist["before_max"] > 0.1 and dist["after_max"] < 1e-6
    assert dist["after"].shape == (12,)
    with pytest.raises(pkmcal.PkmcalError, match="distances"):
        pkmcal.calibrate(delta, commands, measured, axes=["probe"], distances=(ca, cb))
    # A bad distance row is named by its row, from 0, as the poses are.
    same = cb.copy()
    same[5] = ca[5]
    with pytest.raises(pkmcal.PkmcalError) as e:
        pkmcal.calibrate(delta, commands, measured, axes=["probe"], free=free, distances=(ca, same, d))
    assert e.value.pose == 5, str(e.value)
    assert "distance 5" in str(e.value), str(e.value)


def test_a_calibration_saved_and_read_back(tmp_path):
    """Calibration.save writes the calibration record (the CLI's report);
    load_calibration reads it back exactly; it serves predict (with its
    covariance) on its own mechanism only, and the CLI reads it too."""
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 25).targets
    commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=1)
    cal = pkmcal.calibrate(mech, commands, measured, frame="base")
    path = tmp_path / "cal.json"
    cal.save(path)
    saved = pkmcal.load_calibration(path)
    assert saved.version == 1 and saved.mechanism == mech.name
    assert saved.mechanism_identity.startswith("fnv1a64:")
    assert saved.model == cal.model
    assert saved.parameters == cal.parameters
    assert np.array_equal(saved.covariance, cal.covariance)
    a = pkmcal.predict(mech, commands, cal, uncertainty=True)
    b = pkmcal.predict(mech, commands, saved, uncertainty=True)
    assert np.array_equal(a.x, b.x)
    assert np.array_equal(a.covariance, b.covariance)
    # Only its own mechanism.
    delta = pkmcal.Mechanism(EXAMPLES / "linear-delta" / "mechanism.toml")
    with pytest.raises(pkmcal.PkmcalError, match="another mechanism"):
        pkmcal.predict(delta, [[300.0, 300.0, 300.0]], saved)
    # A report of another kind is refused.
    (tmp_path / "other.json").write_text('{"format": "x", "version": 1}')
    with pytest.raises(pkmcal.PkmcalError):
        pkmcal.load_calibration(tmp_path / "other.json")


def test_star_import_keeps_the_builtin_warning():
    """`from pkmcal import *` does not shadow Python's `Warning`."""
    names = {}
    exec("from pkmcal import *", names)
    assert "Warning" not in names
    assert pkmcal.Warning is not Warning


def test_mechanisms_compare_by_description(tmp_path):
    """Two mechanisms read from the same description are equal (and hash
    alike), wherever they were read from; another description is not."""
    a, b = pkmcal.Mechanism(), pkmcal.Mechanism.reference()
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    path = EXAMPLES / "gough-stewart-6" / "mechanism.toml"
    g1, g2 = pkmcal.Mechanism(path), pkmcal.Mechanism.from_toml(path.read_text())
    assert g1 == g2 and hash(g1) == hash(g2)
    assert a != g1 and a != "jeong-kim-2dof"
    import pickle

    assert pickle.loads(pickle.dumps(g1)) == g1


def _reference_data():
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 20).targets
    commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.001, seed=1)
    return mech, commands, measured


def test_named_columns_are_read_by_name_in_any_order():
    pd = pytest.importorskip("pandas")
    mech, commands, measured = _reference_data()
    plain = pkmcal.calibrate(mech, commands, measured, frame="base")
    c = pd.DataFrame(commands, columns=["q1", "q2", "q3"])
    x = pd.DataFrame(measured, columns=["x", "y"])
    for cc, xx in [(c, x), (c[["q3", "q1", "q2"]], x[["y", "x"]]), (c, x.rename(columns={"x": "X", "y": "Y"}))]:
        named = pkmcal.calibrate(mech, cc, xx, frame="base")
        assert named.parameters == plain.parameters
    np.testing.assert_array_equal(
        pkmcal.predict(mech, c[["q2", "q3", "q1"]]).x, pkmcal.predict(mech, commands).x
    )
    # Extra columns are ignored, as in a CSV file; a missing one is named.
    extra = x.assign(note=1.0)[["note", "y", "x"]]
    assert pkmcal.calibrate(mech, c, extra, frame="base").parameters == plain.parameters
    with pytest.raises(pkmcal.PkmcalError, match="measured: missing column `y`"):
        pkmcal.calibrate(mech, c, x.rename(columns={"y": "z"}), frame="base")


def test_structured_arrays_are_read_by_name():
    mech, commands, _ = _reference_data()
    s = np.zeros(len(commands), dtype=[("q3", "f8"), ("q1", "f8"), ("q2", "f8")])
    for k, n in enumerate(["q1", "q2", "q3"]):
        s[n] = commands[:, k]
    np.testing.assert_array_equal(pkmcal.predict(mech, s).x, pkmcal.predict(mech, commands).x)


def test_calibration_warnings_are_python_warnings_once_per_call():
    import warnings

    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 35).targets
    commands, measured = pkmcal.simulate(mech, targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=1)
    # The rigid model cannot see dq3: one IdentifiabilityWarning.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = pkmcal.calibrate(mech, commands, measured, model="rigid", frame="base")
    ours = [w for w in caught if issubclass(w.category, pkmcal.PkmcalWarning)]
    assert ours and all(issubclass(w.category, UserWarning) for w in ours)
    assert any(issubclass(w.category, pkmcal.IdentifiabilityWarning) for w in ours)
    assert len(ours) == len({str(w.message) for w in ours}) == len(set(cal.warnings))
    assert cal.warnings[0] == cal.warnings[0] and hash(cal.warnings[0]) == hash(cal.warnings[0])
    # A clean fit warns nothing.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pkmcal.calibrate(mech, commands, measured, frame="base")
    assert not [w for w in caught if issubclass(w.category, pkmcal.PkmcalWarning)]


def test_a_plan_that_leaves_a_direction_undetermined_says_so():
    mech = pkmcal.Mechanism()
    # The rigid model cannot see dq3: 15 of the 16 directions.
    with pytest.warns(pkmcal.IdentifiabilityWarning, match="determine only 15 of the 16"):
        p = pkmcal.plan(mech, 20, model="rigid", max_candidates=300)
    assert (p.rank, p.free) == (15, 16)
    assert pkmcal.plan(mech, 20, max_candidates=300).rank == 16


def test_a_mechanism_lists_what_it_is_made_of():
    m = pkmcal.Mechanism(EXAMPLES / "gough-stewart-6" / "mechanism.toml")
    s = m.summary
    assert s["dof"] == 6 and s["actuators"] == m.actuators
    assert [p["name"] for p in s["parameters"]] == m.parameters
    assert {p["name"]: p["nominal"] for p in s["parameters"]} == m.nominal
    assert [p["name"] for p in s["parameters"] if p["free_by_default"]] == [
        n for n in m.parameters if n in m.default_free
    ]
    assert [a["name"] for a in s["tool_axes"]] == m.tool_axes
    np.testing.assert_array_equal([a["workspace"] for a in s["tool_axes"]], m.workspace)


def test_the_default_frame_is_the_command_lines_auto():
    """Without frame=, whole positions are read from an instrument frame
    identified with the rest (the CLI's `auto`; arrays never declare the
    base frame), readings of some axes in the base frame; the frame's
    parameters are then among the free ones, or not."""
    m = pkmcal.Mechanism()
    targets = pkmcal.plan(m, 30).targets
    c, x = pkmcal.simulate(m, targets, {"l11": 280.3}, noise=0.002, seed=5)
    auto = pkmcal.calibrate(m, c, x)
    assert {"frame.x", "frame.y", "frame.phi"} <= set(auto.free)
    base = pkmcal.calibrate(m, c, x, frame="base")
    assert not any(n.startswith("frame.") for n in base.free)
    # One axis read: no frame to register, whatever the default.
    part = pkmcal.calibrate(m, c, x[:, :1], axes=["x"])
    assert not any(n.startswith("frame.") for n in part.free)
