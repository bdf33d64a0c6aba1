"""Prediction time per row on distinct rows: near the poses `plan` chooses
(the workspace's edges) against rows spread over a plain grid, nominal and
compensated commands (issue 35). Medians of five calls, one process.

    python benchmarks/predict_rows.py [ROWS]
"""
import sys
import time

import numpy as np
import pkmcal

n = int(sys.argv[1]) if len(sys.argv) > 1 else 100_000
mech = pkmcal.Mechanism()
rng = np.random.default_rng(35)
plan = pkmcal.plan(mech, 35)


def distinct(centres):
    # n distinct targets within 2 mm of the centres.
    t = centres[rng.integers(0, len(centres), n)] + rng.uniform(-2.0, 2.0, (n, 2))
    return t


def med(f):
    times = []
    for _ in range(5):
        s = time.perf_counter()
        f()
        times.append(time.perf_counter() - s)
    return float(np.median(times))


cal = {"l11": 280.3, "dq3": 0.002}
for name, centres in [("near the planned poses", plan.targets), ("near the plain grid", plan.grid_targets)]:
    targets = distinct(np.asarray(centres))
    nominal = pkmcal.compensate(mech, targets, skip_unreachable=True)
    skipped = set(nominal.skipped)
    keep = [i for i in range(n) if i not in skipped]
    c = nominal.commands[keep]
    comp = pkmcal.compensate(mech, targets[keep], cal, skip_unreachable=True).commands
    comp = comp[~np.isnan(comp).any(axis=1)]
    t1 = med(lambda: pkmcal.predict(mech, c))
    t2 = med(lambda: pkmcal.predict(mech, comp, cal))
    print(f"{name}: {len(c)} nominal rows {t1 / len(c) * 1e6:.2f} µs/row; "
          f"{len(comp)} compensated rows {t2 / len(comp) * 1e6:.2f} µs/row")
