"""Every Python entry point on every shipped example, timed (median of
repeats, seconds; plan once). Predict and compensate run on about 2,000 and
500 rows (the plan's poses repeated) and are given per row. Run after
`pip install ./crates/pkmcal-py`:

    python benchmarks/python_api.py [REPEATS]
"""

import pathlib
import statistics
import sys
import time

import numpy as np

import pkmcal

REPO = pathlib.Path(__file__).resolve().parents[1]
REPEATS = int(sys.argv[1]) if len(sys.argv) > 1 else 5


def timed(f):
    times, out = [], None
    for _ in range(REPEATS):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def perturbation(mech):
    units = mech.parameter_units
    step = {"mm": 0.2, "rad": 0.001}
    return {n: mech.nominal[n] + step[units[n]] for n in mech.default_free[::3] if units[n] in step}


def main():
    sources = [None] + sorted(p / "mechanism.toml" for p in (REPO / "examples").iterdir() if (p / "mechanism.toml").exists())
    print(f"{'mechanism':<18} {'poses':>5} {'plan':>7} {'simulate':>9} {'calibrate':>10} {'predict/pose':>13} {'compensate/pose':>16} {'figures':>8}  after max (mm)")
    for src in sources:
        mech = pkmcal.Mechanism(src)
        name = "reference" if src is None else src.parent.name
        count = max(35, 2 * len(mech.default_free) // len(mech.tool_axes) + 10)
        t = time.perf_counter()
        plan = pkmcal.plan(mech, count)  # once: seconds on planar linkages
        t_plan = time.perf_counter() - t
        truth = perturbation(mech)
        t_sim, (c, y) = timed(lambda: pkmcal.simulate(mech, plan.targets, truth, noise=0.002))
        t_cal, cal = timed(lambda: pkmcal.calibrate(mech, c, y))
        many = np.repeat(c, max(1, 2000 // len(c)), axis=0)
        t_pred, _ = timed(lambda: pkmcal.predict(mech, many, cal))
        targets = np.repeat(plan.targets, max(1, 500 // len(c)), axis=0)
        t_comp, _ = timed(lambda: pkmcal.compensate(mech, targets, cal, skip_unreachable=True))
        t_fig, figs = timed(lambda: cal.figures())
        assert cal.converged and len(figs) >= 4
        print(
            f"{name:<18} {len(c):>5} {t_plan:7.3f} {t_sim:9.4f} {t_cal:10.4f} {t_pred / len(many) * 1e6:10.1f} µs {t_comp / len(targets) * 1e6:13.1f} µs {t_fig:8.3f}  {cal.after.distance_max:.4f}"
        )


if __name__ == "__main__":
    main()
