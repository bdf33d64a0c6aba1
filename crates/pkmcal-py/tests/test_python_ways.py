"""What a user of NumPy, pandas and scipy expects of a Python package:
Python's own exceptions (files are OSErrors, bad numbers ValueErrors naming
the argument, wrong types TypeErrors), names given as a string or a
sequence, signatures whose defaults are values, stubs that match, option
groups, and reprs and docstrings that say what is there."""

import inspect
import os
import pathlib
import shutil
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import pkmcal
from conftest import EXAMPLES

TRUTH = {"l11": 280.3, "dq3": 0.002}


@pytest.fixture(scope="module")
def ref():
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 35).targets
    c, y = pkmcal.simulate(mech, targets, TRUTH, noise=0.002, seed=1)
    return mech, c, y


def test_file_problems_are_oserrors_and_pkmcal_errors(tmp_path, ref):
    mech, c, y = ref
    missing = tmp_path / "missing.toml"
    for call in (
        lambda: pkmcal.Mechanism(missing),
        lambda: pkmcal.load_calibration(missing),
        lambda: pkmcal.Calibration.load(missing),
        lambda: pkmcal.predict(mech, c, missing),
        lambda: pkmcal.drift(missing, mechanism=mech),
    ):
        with pytest.raises(FileNotFoundError) as e:
            call()
        assert isinstance(e.value, pkmcal.PkmcalError) and isinstance(e.value, OSError)
        assert e.value.errno == 2 and e.value.filename == str(missing)
        assert "missing.toml" in str(e.value)
    # A directory where a file is expected.
    with pytest.raises(IsADirectoryError) as e:
        pkmcal.load_calibration(tmp_path)
    assert isinstance(e.value, pkmcal.PkmcalError)
    # Writing where nothing can be written: the directory does not exist.
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    with pytest.raises(OSError) as e:
        cal.save(tmp_path / "no-such-dir" / "cal.json")
    assert isinstance(e.value, pkmcal.PkmcalError)
    if os.geteuid() != 0:  # root reads everything
        locked = tmp_path / "locked.toml"
        shutil.copy(EXAMPLES / "five-bar" / "mechanism.toml", locked)
        locked.chmod(0)
        with pytest.raises(PermissionError):
            pkmcal.Mechanism(locked)


def test_integers_out_of_range_are_value_errors_naming_the_argument(ref):
    mech, c, y = ref
    with pytest.raises(ValueError, match="kfold=-2"):
        pkmcal.calibrate(mech, c, y, kfold=-2, frame="base")
    with pytest.raises(ValueError, match="count=-1"):
        pkmcal.plan(mech, -1)
    with pytest.raises(ValueError, match="n=-1"):
        pkmcal.set_threads(-1)
    with pytest.raises(ValueError, match="n=100000"):
        pkmcal.set_threads(100_000)
    with pytest.raises(ValueError, match="runs=-5"):
        pkmcal.montecarlo(mech, y, runs=-5)
    with pytest.raises(ValueError, match=r"max_nfev=1180591620717411303424"):
        pkmcal.calibrate(mech, c, y, max_nfev=2**70, frame="base")
    # The library's bounds on work, named as the keyword (the command line's
    # --grid, --samples, --runs, --validation-targets and --count).
    with pytest.raises(ValueError, match="grid=10001: more than the 10000 targets"):
        pkmcal.budget(mech, {"l11": 0.01}, grid=10_001)
    with pytest.raises(ValueError, match="grid=100000: more than the 10000 targets"):
        pkmcal.drift(pkmcal.calibrate(mech, c, y, frame="base"), grid=100_000)
    with pytest.raises(ValueError, match="count=10001: more than the 10000 targets"):
        pkmcal.plan(mech, 10_001)
    with pytest.raises(ValueError, match="validation=10001: more than the 10000 targets"):
        pkmcal.montecarlo(mech, y, runs=2, validation=10_001)
    with pytest.raises(ValueError, match="samples=1000001: more than the 1000000 machines"):
        pkmcal.budget(mech, {"l11": 0.01}, samples=1_000_001)
    with pytest.raises(ValueError, match="runs=1000001: more than the 1000000 simulated"):
        pkmcal.montecarlo(mech, y, runs=1_000_001)
    # NumPy integers are integers.
    assert pkmcal.plan(mech, np.int64(12), max_candidates=np.int32(300)).targets.shape == (12, 2)
    assert pkmcal.calibrate(mech, c, y, seed=np.int64(3), holdout=0.2, frame="base").validation
    # A float where a count is wanted is a type error, named.
    with pytest.raises(TypeError, match="kfold: expected a whole number, got float"):
        pkmcal.calibrate(mech, c, y, kfold=2.5, frame="base")


def test_names_are_a_string_or_a_sequence(ref):
    mech, c, y = ref
    a = pkmcal.calibrate(mech, c, y, frame="base", free="l11,l12", fix=["l12"])
    assert a.free == ["l11"]
    only_x = pkmcal.simulate(mech, pkmcal.plan(mech, 12, max_candidates=300).targets, TRUTH, seed=1, axes="x")
    assert only_x[1].shape == (12, 1)
    b = pkmcal.calibrate(mech, only_x[0], only_x[1], axes="x", free=("l11", "dq1"), frame="base")
    assert b.axes == ["x"] and b.free == ["l11", "dq1"]
    assert pkmcal.predict(mech, c, outputs=("x", "q")).torque is None
    with pytest.raises(TypeError, match="free: expected a name"):
        pkmcal.calibrate(mech, c, y, free=3, frame="base")
    with pytest.raises(pkmcal.PkmcalError, match="outputs: unknown `torques`.*did you mean \"torque\""):
        pkmcal.predict(mech, c, outputs="torques")


def test_drift_refuses_a_calibration_of_another_mechanism(ref, tmp_path):
    mech, c, y = ref
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    for other in ("five-bar", "jeong-kim-planar"):
        m = pkmcal.Mechanism(EXAMPLES / other / "mechanism.toml")
        with pytest.raises(pkmcal.PkmcalError, match="calibration of another mechanism"):
            pkmcal.drift(cal, mechanism=m)
        cal.save(tmp_path / "cal.json")
        with pytest.raises(pkmcal.PkmcalError, match="calibration of another mechanism"):
            pkmcal.drift(tmp_path / "cal.json", mechanism=m)
    # Its own mechanism (the same description from elsewhere) is taken.
    assert pkmcal.drift(cal, mechanism=pkmcal.Mechanism()).parameters


def test_reprs_and_docstrings_say_what_is_there(ref):
    mech, c, y = ref
    # σ known: the joint test is χ² (an estimated σ makes it F, whose p
    # does not underflow here).
    cal = pkmcal.calibrate(mech, c, y, frame="base", sigma=0.002)
    d = pkmcal.drift(cal, grid=10)
    assert "0.000e0" not in repr(d)
    # Drifted 0.3 mm against a σ of µm: p underflows, and says so.
    assert d.chi2[2] == 0 and "joint p < 1e-300" in repr(d)
    doc = pkmcal.calibrate.__doc__
    assert "each one's tolerance and share" not in doc
    assert "Calibration.from_data" in doc and "to_pandas()" in doc


def test_calibration_load_reads_on_the_class_and_is_the_load_on_a_calibration(ref, tmp_path):
    mech, c, y = ref
    plain = pkmcal.calibrate(mech, c, y, frame="base")
    assert plain.load is None
    loaded = pkmcal.calibrate(mech, c, y, frame="base", load=[5.0, -2.0])
    np.testing.assert_array_equal(loaded.load, [5.0, -2.0])
    loaded.save(tmp_path / "cal.json")
    back = pkmcal.Calibration.load(tmp_path / "cal.json")
    assert back == loaded
    np.testing.assert_array_equal(back.load, [5.0, -2.0])
    assert callable(pkmcal.Calibration.load)


def test_skip_unreachable_skips_a_row_with_a_nan(ref):
    mech, c, _ = ref
    rows = c[:3].copy()
    rows[1, 0] = np.nan
    with pytest.raises(pkmcal.PkmcalError, match="row 1"):
        pkmcal.predict(mech, rows)
    p = pkmcal.predict(mech, rows, skip_unreachable=True)
    assert p.skipped == [1] and np.all(np.isnan(p.x[1])) and np.all(np.isfinite(p.x[[0, 2]]))
    np.testing.assert_array_equal(p.x[[0, 2]], pkmcal.predict(mech, c[[0, 2]]).x)
    t = pkmcal.plan(mech, 12, max_candidates=300).targets[:3]
    t[2, 1] = np.nan
    comp = pkmcal.compensate(mech, t, skip_unreachable=True)
    assert comp.skipped == [2]


def test_defaults_are_values_in_every_signature():
    for name in pkmcal.__all__:
        f = getattr(pkmcal, name)
        if not inspect.isfunction(f):
            continue
        for p in inspect.signature(f).parameters.values():
            assert p.default is not Ellipsis, f"{name}({p.name}=...)"
    sig = inspect.signature(pkmcal.calibrate).parameters
    assert sig["seed"].default == 1 and sig["stated_readings"].default == 10.0
    assert sig["outlier_threshold"].default == 4.0
    assert inspect.signature(pkmcal.analyze).parameters["stated_noise"].default == 0.002


def test_the_stubs_match_the_package():
    pytest.importorskip("mypy")
    allowlist = pathlib.Path(__file__).parents[1] / "stubtest-allowlist.txt"
    r = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "pkmcal", "--allowlist", str(allowlist)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_option_groups_are_the_keywords(ref):
    mech, c, y = ref
    flat = pkmcal.calibrate(mech, c, y, frame="base", stated_noise=0.002, max_nfev=50, loss="huber", holdout=0.2, kfold=3, seed=4)
    grouped = pkmcal.calibrate(
        mech,
        c,
        y,
        instrument=pkmcal.Instrument(frame="base", stated_noise=0.002),
        solver=pkmcal.Solver(max_nfev=50, loss="huber"),
        validation=pkmcal.Validation(holdout=0.2, kfold=3, seed=4),
    )
    assert grouped == flat
    vc, vy = c[:10], y[:10]
    assert pkmcal.calibrate(mech, c, y, frame="base", validation=pkmcal.Validation(data=(vc, vy))) == pkmcal.calibrate(
        mech, c, y, frame="base", validation=(vc, vy)
    )
    with pytest.raises(TypeError, match="give frame once"):
        pkmcal.calibrate(mech, c, y, frame="free", instrument=pkmcal.Instrument(frame="base"))
    with pytest.raises(TypeError, match="solver: expected a pkmcal.Solver"):
        pkmcal.calibrate(mech, c, y, solver={"max_nfev": 5})
    ident = pkmcal.analyze(mech, c, y, instrument=pkmcal.Instrument(frame="base"))
    assert ident == pkmcal.analyze(mech, c, y, frame="base")


def test_the_stated_noise_has_one_name(ref):
    mech, c, y = ref
    tol = {"l11": 0.05}
    a = pkmcal.analyze(mech, c, y, frame="base", tolerances=tol, stated_noise=0.004)
    with pytest.warns(DeprecationWarning, match="noise= is deprecated.*stated_noise="):
        b = pkmcal.analyze(mech, c, y, frame="base", tolerances=tol, noise=0.004)
    assert a == b
    with pytest.warns(DeprecationWarning):
        p = pkmcal.plan(mech, 12, max_candidates=300, noise=0.004, tolerances=tol)
    assert p == pkmcal.plan(mech, 12, max_candidates=300, stated_noise=0.004, tolerances=tol)
    with pytest.raises(TypeError, match="give stated_noise once"):
        pkmcal.budget(mech, tol, stated_noise=0.003, noise=0.004)
    # noise= stays the simulated noise where it is simulated, unwarned.
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        pkmcal.simulate(mech, y[:5], noise=0.002, seed=1)


def test_the_stubs_accept_the_calls_that_work(tmp_path):
    """mypy --strict takes what the package takes: paths as os.PathLike,
    validation as a list, NumPy integers as seeds and counts, names as a
    string, the option groups, and `cal.load` both ways."""
    pytest.importorskip("mypy")
    code = tmp_path / "uses.py"
    code.write_text(
        textwrap.dedent(
            """
            import pathlib
            from typing import Optional

            import numpy as np
            import numpy.typing as npt

            import pkmcal

            mech = pkmcal.Mechanism(pathlib.Path("m.toml"))
            c = np.zeros((3, 3))
            cal = pkmcal.calibrate(
                mech, c, c, validation=[c, c], seed=np.int64(3), axes="x", kfold=np.int64(3),
                instrument=pkmcal.Instrument(frame="base"), solver=pkmcal.Solver(max_nfev=5),
            )
            load: Optional[npt.NDArray[np.float64]] = cal.load
            back: pkmcal.Calibration = pkmcal.Calibration.load(pathlib.Path("cal.json"))
            saved = pkmcal.load_calibration(pathlib.Path("cal.json"))
            p = pkmcal.predict(mech, c, saved, outputs="x")
            x: npt.NDArray[np.float64] = p.x
            pkmcal.plan(mech, np.int64(12), stated_noise=0.002).to_pandas()
            pkmcal.drift(pathlib.Path("new.json"), pathlib.Path("old.json"), mechanism=mech)
            """
        )
    )
    r = subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--no-incremental", str(code)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_pandas_stays_optional():
    """Without pandas every call works on arrays; to_pandas says what it
    needs."""
    script = textwrap.dedent(
        """
        import sys
        sys.modules["pandas"] = None  # import pandas now fails
        import warnings
        warnings.simplefilter("ignore")
        import pkmcal
        m = pkmcal.Mechanism()
        c, y = pkmcal.simulate(m, pkmcal.plan(m, 35).targets, {"l11": 280.3}, noise=0.002, seed=1)
        cal = pkmcal.calibrate(m, c, y, frame="base")
        assert abs(cal.parameters["l11"] - 280.3) < 0.01
        assert pkmcal.predict(m, c, cal).x.shape == (35, 2)
        assert "<table" in cal._repr_html_()
        try:
            cal.to_pandas()
        except ImportError as e:
            print(e)
        """
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "to_pandas needs pandas" in r.stdout
