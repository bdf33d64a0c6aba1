"""Ctrl-C during a long call: the call stops at its next step (a row, a
pose, a sample, a target, a run, a candidate, an evaluation) and raises
Python's KeyboardInterrupt, never a panic, and the interpreter goes on.
Judged by the outcome: each call below would take a minute or more; a child
process sends itself SIGINT a moment after starting it, and must see the
KeyboardInterrupt promptly after the signal."""

import subprocess
import sys
import textwrap

import pytest

# Seconds the child may take in all: far below what the interrupted calls
# would take to finish, far above the time it takes to set them up.
FINISHED_LONG_BEFORE_S = 120
# Seconds from the signal to the KeyboardInterrupt: generous beside the
# half second a call takes to stop, far below the minute it would go on.
PROMPT_S = 5.0

# What the calls work on (each set up in a few seconds).
SETUP = """
import numpy as np
import pkmcal
EX = {examples!r}
mech = pkmcal.Mechanism()
jk = pkmcal.Mechanism(EX + "/jeong-kim-planar/mechanism.toml")
rrr = pkmcal.Mechanism(EX + "/4-rrr/mechanism.toml")
hexapod = pkmcal.Mechanism(EX + "/gough-stewart-8/mechanism.toml")
rng = np.random.default_rng(1)

def inner(m, n, share=0.3):
    # n targets well inside the workspace (reachable), 1,000 distinct.
    w = m.workspace
    c, h = w.mean(axis=1), (w[:, 1] - w[:, 0]) * share / 2
    t = c + rng.uniform(-1, 1, (2000, len(c))) * h
    comp = pkmcal.compensate(m, t, model="rigid", skip_unreachable=True)
    t = t[np.all(np.isfinite(comp.commands), axis=1)][:1000]
    return np.repeat(t, n // len(t) + 1, axis=0)[:n] + rng.uniform(-1e-3, 1e-3, (n, t.shape[1]))
"""

CALLS = {
    # 10^6 simulated calibrations: about ten minutes on two cores.
    "montecarlo": (
        "targets = pkmcal.plan(mech, 35).targets",
        "pkmcal.montecarlo(mech, targets, runs=1_000_000)",
    ),
    # 1,000 of 8,820 candidates for 56 parameters: minutes (300 take one).
    "plan": ("", "pkmcal.plan(hexapod, 1000, spacing=1.0, max_candidates=200_000)"),
    # Leave-one-out cross-validation of 3,000 poses: 3,000 fits of 2,999.
    "calibrate": (
        "t = inner(mech, 3000); c, y = pkmcal.simulate(mech, t, {'l11': 280.3}, noise=0.002, seed=1)",
        "pkmcal.calibrate(mech, c, y, kfold=3000, frame='base')",
    ),
    # 10^6 machines drawn through the exact model at 200 targets: 20 minutes.
    "budget": ("", "pkmcal.budget(mech, {'l11': 0.01, 'D1': 0.01}, samples=1_000_000)"),
    # 3·10^6 rows of a planar linkage: over a minute.
    "predict": (
        "c = np.tile(pkmcal.nominal_commands(jk, inner(jk, 1000)), (3000, 1))",
        "pkmcal.predict(jk, c, outputs='x')",
    ),
    # 5·10^5 targets of a planar linkage: over a minute.
    "compensate": ("t = inner(jk, 500_000)", "pkmcal.compensate(jk, t)"),
    # 5·10^5 targets, one after the other: two minutes.
    "simulate": ("t = inner(jk, 500_000)", "pkmcal.simulate(jk, t, seed=1)"),
    # The most poses an analysis takes, of a four-bar linkage: a quarter of a minute.
    "analyze": (
        "t = inner(rrr, 1000, 0.2); c = np.tile(pkmcal.nominal_commands(rrr, t), (100, 1)); t = np.tile(t, (100, 1))",
        "pkmcal.analyze(rrr, c, t, frame='base')",
    ),
    # The change at the tool over the most workspace targets one request
    # spreads (10^4), of a planar linkage: ten seconds and more.
    "drift": (
        "t = pkmcal.plan(jk, 35).targets; c, y = pkmcal.simulate(jk, t, noise=0.002, seed=1)\n"
        "cal = pkmcal.calibrate(jk, c, y, frame='base')",
        "pkmcal.drift(cal, grid=10_000)",
    ),
    # The figures of 5·10^5 poses without targets: each one's position
    # predicted first (the figures then show a selection).
    "figures": ("cal = big_calibration(jk, 500_000)", "cal.figures()"),
    "save_report": ("cal = big_calibration(jk, 500_000)", "cal.save_report(out)"),
    # The record of 5·10^5 poses: its JSON text takes ten seconds to write.
    "save": ("cal = big_calibration(jk, 500_000)", "cal.save(out)"),
}

# A calibration of many poses, made quickly: one of 100 poses, its poses
# repeated in its pickled columns (see pkmcal/_pkmcal's pickle format).
BIG = """
import zlib

def _column(packed):
    n, planes = packed
    a = np.zeros(n, np.uint64)
    for k, (deflated, b) in enumerate(planes):
        b = zlib.decompress(b) if deflated else b
        a |= np.frombuffer(b, np.uint8).astype(np.uint64) << np.uint64(8 * k)
    return a

def _packed(a):
    a = np.asarray(a, np.uint64)
    return (len(a), [(False, ((a >> np.uint64(8 * k)) & np.uint64(255)).astype(np.uint8).tobytes()) for k in range(8)])

def big_calibration(m, n):
    c, y = pkmcal.simulate(m, inner(m, 100), noise=0.002, seed=1)
    cal = pkmcal.calibrate(m, c, y, frame="base")
    make, (mechanism, d) = cal.__reduce__()
    times = n // 100
    for k in list(d):
        if k.endswith("_values") or k.endswith("_lens") or k in ("sigma_known", "origin", "pose", "line"):
            if k.startswith(("residuals", "sigmas", "jacobian")):
                continue
            d[k] = _packed(np.tile(_column(d[k]), times))
    return make(mechanism, d)
"""


@pytest.mark.parametrize("call", sorted(CALLS))
def test_ctrl_c_stops_a_long_call_promptly_with_keyboard_interrupt(call, tmp_path):
    from conftest import EXAMPLES

    setup, work = CALLS[call]
    script = (
        SETUP.format(examples=str(EXAMPLES))
        + BIG
        + setup
        + textwrap.dedent(
            f"""
            import os, signal, sys, threading, time
            out = {str(tmp_path / "report")!r}
            sent = []
            def interrupt():
                sent.append(time.perf_counter())
                os.kill(os.getpid(), signal.SIGINT)
            threading.Timer(2.0, interrupt).start()
            try:
                {work}
            except KeyboardInterrupt:
                after = time.perf_counter() - sent[0]
                # The interpreter goes on: another call works.
                assert pkmcal.predict(mech, pkmcal.nominal_commands(mech, [0.0, 200.0])).x.shape == (2,)
                print(f"interrupted {{after:.3f}} s after the signal")
                sys.exit(0)
            print("finished without interruption")
            sys.exit(1)
            """
        )
    )
    p = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=FINISHED_LONG_BEFORE_S,
    )
    assert p.returncode == 0 and "interrupted" in p.stdout, p.stdout + p.stderr
    assert "PanicException" not in p.stderr, p.stderr
    after = float(p.stdout.split("interrupted ")[1].split(" s")[0])
    assert after < PROMPT_S, p.stdout
    if call in ("save", "save_report"):
        # Nothing half written.
        assert not (tmp_path / "report").exists()
