"""Ctrl-C during a long call: the call stops at its next step (one run, one
candidate, one evaluation) and raises Python's KeyboardInterrupt, never a
panic. Judged by the outcome: each call below would take minutes to finish;
a child process that gets SIGINT a moment after starting it must end with a
KeyboardInterrupt long before that."""

import subprocess
import sys
import textwrap

import pytest

# Seconds the child may take in all: far below what the interrupted call
# would take to finish (minutes), far above the time it takes to start.
FINISHED_LONG_BEFORE_S = 60

CALLS = {
    # 10^6 simulated calibrations: about ten minutes on two cores.
    "montecarlo": "pkmcal.montecarlo(mech, targets, runs=1_000_000)",
    # 1,000 of 8,820 candidates for 56 parameters: minutes (300 take one).
    "plan": "pkmcal.plan(hexapod, 1000, spacing=1.0, max_candidates=200_000)",
    # Leave-one-out cross-validation of 3,000 poses: 3,000 fits of 2,999.
    "calibrate": "pkmcal.calibrate(mech, many_c, many_x, kfold=3000, frame='base')",
}


@pytest.mark.parametrize("call", sorted(CALLS))
def test_ctrl_c_stops_a_long_call_with_keyboard_interrupt(call, tmp_path):
    from conftest import EXAMPLES

    script = textwrap.dedent(
        f"""
        import os, signal, sys, threading, time
        import numpy as np
        import pkmcal
        mech = pkmcal.Mechanism()
        targets = pkmcal.plan(mech, 35).targets
        hexapod = pkmcal.Mechanism({str(EXAMPLES / "gough-stewart-8" / "mechanism.toml")!r})
        many = np.repeat(targets, 86, axis=0) + np.random.default_rng(1).uniform(-1, 1, (35 * 86, 2))
        many_c, many_x = pkmcal.simulate(mech, many, {{"l11": 280.3}}, noise=0.002, seed=1)
        threading.Timer(2.0, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        try:
            {CALLS[call]}
        except KeyboardInterrupt:
            print("interrupted")
            sys.exit(0)
        print("finished without interruption")
        sys.exit(1)
        """
    )
    p = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=FINISHED_LONG_BEFORE_S,
    )
    assert p.returncode == 0 and "interrupted" in p.stdout, p.stdout + p.stderr
    assert "PanicException" not in p.stderr, p.stderr
