"""Big data and many threads: results pickle in binary, figures of many
poses show a selection and say so, predict keeps only the outputs asked
for, calls from two threads compute side by side, and results with a table
show it in a notebook."""

import pickle
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

import pkmcal
from conftest import EXAMPLES

TRUTH = {"l11": 280.3, "dq3": 0.002}

# Seconds after which a call in a thread is taken for blocked.
BLOCKED_S = 300


def many_poses(n, seed=1):
    mech = pkmcal.Mechanism()
    t = pkmcal.plan(mech, 35).targets
    rng = np.random.default_rng(seed)
    targets = np.repeat(t, n // 35 + 1, axis=0)[:n] + rng.uniform(-0.5, 0.5, (n, 2))
    c, y = pkmcal.simulate(mech, targets, TRUTH, noise=0.002, seed=seed)
    return mech, c, y


def test_a_calibration_pickles_in_binary_to_the_bit():
    mech, c, y = many_poses(5000)
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    data = pickle.dumps(cal)
    back = pickle.loads(data)
    assert back == cal
    np.testing.assert_array_equal(back.jac, cal.jac)
    np.testing.assert_array_equal(back.residuals, cal.residuals)
    assert back.summary() == cal.summary()
    # Binary: no JSON record inside, and far smaller than the record's text
    # (which is what pickling wrote before).
    assert b'"pkmcal_version"' not in data
    record = pickle.loads(pickle.dumps(cal, protocol=0)) == cal
    assert record
    import json
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        cal.save(f"{d}/cal.json")
        text = open(f"{d}/cal.json").read()
    assert json.loads(text)["state"]
    assert 5 * len(data) < len(text), (len(data), len(text))


def test_a_saved_calibration_of_many_poses_reads_back(tmp_path):
    # A record holds every pose: 35,000 poses write more than the 16 MiB
    # a setting may have; it is read within a data file's limit.
    mech, c, y = many_poses(35_000)
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    cal.save(tmp_path / "cal.json")
    assert (tmp_path / "cal.json").stat().st_size > 16 << 20
    assert pkmcal.Calibration.load(tmp_path / "cal.json") == cal
    saved = pkmcal.load_calibration(tmp_path / "cal.json")
    assert saved.parameters == cal.parameters
    assert pkmcal.drift(tmp_path / "cal.json", cal).parameters


def test_a_pickle_written_as_a_record_still_reads():
    mech, c, y = many_poses(40)
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        cal.save(f"{d}/cal.json")
        text = open(f"{d}/cal.json").read()
    # What `__reduce__` gave before: the mechanism and the record's text.
    assert pkmcal.Calibration._from_pickle(cal.mechanism, text) == cal


def test_figures_of_many_poses_show_a_selection_and_say_so():
    mech, c, y = many_poses(20_000)
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    figs = {f.name: f for f in cal.figures()}
    for name in ("errors", "workspace"):
        assert "3000 are drawn" in figs[name].caption, figs[name].caption
    assert "The Q–Q plot draws" in figs["residuals"].caption
    # A few MB at most, whatever the data.
    assert all(len(f.svg) < 5_000_000 for f in figs.values()), {n: len(f.svg) for n, f in figs.items()}
    few = pkmcal.calibrate(mech, c[:500], y[:500], frame="base")
    assert all("spread evenly" not in f.caption for f in few.figures())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_predict_keeps_only_the_outputs_asked_for():
    # Peak memory of the call, measured in a process of its own: within
    # twice the output (the tool poses), where all four outputs are three
    # times more.
    script = textwrap.dedent(
        """
        import numpy as np, pkmcal

        def peak():
            # The peak resident memory of this program (VmHWM: ru_maxrss
            # would keep the parent's, from before exec).
            for line in open("/proc/self/status"):
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024

        mech = pkmcal.Mechanism()
        # Targets without a plan (whose candidate lattice would set the
        # peak first).
        t = np.array([[x, y] for x in np.linspace(-20, 20, 7) for y in np.linspace(180, 220, 5)])
        c = np.tile(pkmcal.nominal_commands(mech, t), (1_000_000 // 35 + 1, 1))[:1_000_000]
        c = np.ascontiguousarray(c)
        pkmcal.predict(mech, c[:1000], outputs="x")  # threads and caches made
        before = peak()
        x = pkmcal.predict(mech, c, outputs="x").x
        after = peak()
        print(after - before, x.nbytes)
        """
    )
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=BLOCKED_S)
    assert p.returncode == 0, p.stderr
    grown, output = map(int, p.stdout.split())
    assert grown <= 2 * output, (grown, output)
    mech = pkmcal.Mechanism()
    c = pkmcal.nominal_commands(mech, pkmcal.plan(mech, 35).targets)
    x = pkmcal.predict(mech, c, outputs="x")
    assert x.q is None and x.torque is None and x.deflection is None
    np.testing.assert_array_equal(x.x, pkmcal.predict(mech, c).x)


def test_calls_from_two_threads_run_side_by_side():
    """A short call in one thread finishes while a long one runs in
    another: each has threads of its own (one each here), where a shared
    pool would have queued the short one behind the long one."""
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 35).targets
    pkmcal.set_threads(1)
    try:
        long_done = threading.Event()

        def long_call():
            pkmcal.montecarlo(mech, targets, runs=4000)
            long_done.set()

        t = threading.Thread(target=long_call)
        t.start()
        time.sleep(0.5)
        c = pkmcal.nominal_commands(mech, targets)
        short = pkmcal.predict(mech, c)
        assert not long_done.is_set(), "the long call ended first: make it longer"
        t.join(BLOCKED_S)
        np.testing.assert_allclose(short.x, targets, atol=1e-9)
    finally:
        pkmcal.set_threads(0)


def test_results_with_a_table_show_it_in_a_notebook():
    mech, c, y = many_poses(40)
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    plan = pkmcal.plan(mech, 12, max_candidates=300)
    results = [
        cal,
        cal.identifiability,
        cal.after,
        plan,
        pkmcal.montecarlo(mech, plan.targets, runs=4, validation=5),
        pkmcal.budget(mech, {"l11": 0.01}, samples=0),
        pkmcal.drift(cal, grid=10),
        pkmcal.predict(mech, c, cal),
        pkmcal.compensate(mech, plan.targets, cal),
    ]
    for r in results:
        html = r._repr_html_()
        assert "<table>" in html and "</table>" in html, type(r).__name__
    assert "l11" in results[6]._repr_html_()
