"""Big data and threads in the Python package (issue 51): the size and time
of pickling a calibration of 100,000 poses, the wall time of the same call
from one thread and from two at once, and the peak memory a predict of
1,000,000 rows adds. Medians of REPEATS; each peak in a process of its own.
Runs against any build of the package (the one installed):

    python benchmarks/python_big.py [REPEATS]
"""

import inspect
import os
import pickle
import statistics
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np

import pkmcal

REPEATS = int(sys.argv[1]) if len(sys.argv) > 1 else 5
TRUTH = {"l11": 280.3, "dq3": 0.002}


def median_time(f):
    times = []
    for _ in range(REPEATS):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def poses(n):
    mech = pkmcal.Mechanism()
    t = pkmcal.plan(mech, 35).targets
    rng = np.random.default_rng(1)
    targets = np.repeat(t, n // 35 + 1, axis=0)[:n] + rng.uniform(-0.5, 0.5, (n, 2))
    c, y = pkmcal.simulate(mech, targets, TRUTH, noise=0.002, seed=1)
    return mech, c, y


def pickling():
    mech, c, y = poses(100_000)
    cal = pkmcal.calibrate(mech, c, y, frame="base")
    data = pickle.dumps(cal, protocol=pickle.HIGHEST_PROTOCOL)
    dumps = median_time(lambda: pickle.dumps(cal, protocol=pickle.HIGHEST_PROTOCOL))
    loads = median_time(lambda: pickle.loads(data))
    assert pickle.loads(data) == cal
    print(f"pickle of 100,000 poses: {len(data) / 1e6:.1f} MB, dumps {dumps:.3f} s, loads {loads:.3f} s")


def two_threads(name, call):
    """The wall time of `call` from one thread and from two at once (medians),
    and the CPU time per wall second of the two: 2 on two idle cores when
    they compute side by side, 1 when one waits for the other."""
    call()

    def both():
        ts = [threading.Thread(target=call) for _ in range(2)]
        for t in ts:
            t.start()
        for t in ts:
            t.join()

    ones, twos, use = [], [], []
    for _ in range(REPEATS):
        t = time.perf_counter()
        call()
        ones.append(time.perf_counter() - t)
        t, c = time.perf_counter(), time.process_time()
        both()
        twos.append(time.perf_counter() - t)
        use.append((time.process_time() - c) / twos[-1])
    one, two = statistics.median(ones), statistics.median(twos)
    procs = statistics.median(two_processes(call) for _ in range(REPEATS))
    print(
        f"{name}: one thread {one:.3f} s, two at once {two:.3f} s: speed-up {2 * one / two:.2f}, "
        f"{statistics.median(use):.2f} CPU s per s; two processes at once {procs:.3f} s "
        f"(load average {os.getloadavg()[0]:.1f})"
    )


def _timed_in_process(call, barrier, out):
    barrier.wait()
    out.put((time.time(), (call(), time.time())[1]))


def two_processes(call):
    """The wall time of `call` run in two forked processes at once: what the
    machine allows two computations side by side (the control)."""
    import multiprocessing

    ctx = multiprocessing.get_context("fork")
    barrier, out = ctx.Barrier(2), ctx.Queue()
    ps = [ctx.Process(target=_timed_in_process, args=(call, barrier, out)) for _ in range(2)]
    for p in ps:
        p.start()
    spans = [out.get() for _ in ps]
    for p in ps:
        p.join()
    return max(e for _, e in spans) - min(s for s, _ in spans)


def beside_a_long_call(n):
    """How long a short call (a predict of 35 rows) takes in one thread while
    a long one (a Monte Carlo study) runs in another: with a shared pool it
    waits for the long one."""
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 35).targets
    c = pkmcal.nominal_commands(mech, targets)
    pkmcal.set_threads(n)
    try:
        waits = []
        for _ in range(REPEATS):
            t = threading.Thread(target=lambda: pkmcal.montecarlo(mech, targets, runs=1500))
            t.start()
            time.sleep(0.3)
            start = time.perf_counter()
            pkmcal.predict(mech, c)
            waits.append(time.perf_counter() - start)
            t.join()
        print(
            f"a predict of 35 rows beside a Monte Carlo study, set_threads({n}): "
            f"{statistics.median(waits) * 1000:.2f} ms (load average {os.getloadavg()[0]:.1f})"
        )
    finally:
        pkmcal.set_threads(0)


def threads():
    beside_a_long_call(1)
    beside_a_long_call(0)
    mech, c, y = poses(2000)
    small_c, small_y = c[:70], y[:70]
    ten = lambda: [pkmcal.calibrate(mech, c, y, frame="base") for _ in range(10)]
    for n in (1, 0):
        pkmcal.set_threads(n)
        try:
            two_threads(f"10 calibrations of 2,000 poses, set_threads({n})", ten)
            two_threads(
                f"20 calibrations of 70 poses, set_threads({n})",
                lambda: [pkmcal.calibrate(mech, small_c, small_y, frame="base") for _ in range(20)],
            )
        finally:
            pkmcal.set_threads(0)


PEAK = """
import numpy as np, pkmcal

def peak():
    # The peak resident memory of this program (VmHWM: ru_maxrss would keep
    # the parent's, from before exec).
    for line in open('/proc/self/status'):
        if line.startswith('VmHWM:'):
            return int(line.split()[1]) * 1024

mech = pkmcal.Mechanism()
# Targets without a plan (whose candidate lattice would set the peak first).
t = np.array([[x, y] for x in np.linspace(-20, 20, 7) for y in np.linspace(180, 220, 5)])
c = np.tile(pkmcal.nominal_commands(mech, t), (1_000_000 // 35 + 1, 1))[:1_000_000]
c = np.ascontiguousarray(c)
pkmcal.predict(mech, c[:1000], {kw})
before = peak()
p = pkmcal.predict(mech, c, {kw})
after = peak()
out = sum(a.nbytes for a in (p.x, p.q, p.torque, p.deflection) if a is not None)
print(after - before, p.x.nbytes, out)
"""


def peak():
    kws = [""]
    if "outputs" in inspect.signature(pkmcal.predict).parameters:
        kws.append("outputs='x'")
    for kw in kws:
        runs = []
        for _ in range(REPEATS):
            r = subprocess.run(
                [sys.executable, "-c", textwrap.dedent(PEAK.format(kw=kw))],
                capture_output=True,
                text=True,
                check=True,
            )
            runs.append([int(v) for v in r.stdout.split()])
        grown = statistics.median(r[0] for r in runs)
        x, out = runs[0][1], runs[0][2]
        print(
            f"predict of 1,000,000 rows ({kw or 'every output'}): peak memory +{grown / 1e6:.0f} MB "
            f"for {out / 1e6:.0f} MB returned (x alone {x / 1e6:.0f} MB)"
        )


if __name__ == "__main__":
    print(f"pkmcal {pkmcal.__version__} from {pkmcal.__file__}")
    pickling()
    threads()
    peak()
