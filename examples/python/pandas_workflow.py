"""A calibration kept in pandas from start to end: measurements as
DataFrames (columns by name, rows by index), the calibration's option groups,
the parameters and the predictions back as DataFrames.

    python examples/python/pandas_workflow.py

It simulates a measurement campaign, stores it as the CSV a laser tracker's
software would export (a pose label per row, columns in its own order),
reads it back with pandas, calibrates, and writes the parameters and the
predicted positions as CSV.
"""

import io

import numpy as np
import pandas as pd  # type: ignore[import-untyped,unused-ignore]

import pkmcal

mech = pkmcal.Mechanism()
plan = pkmcal.plan(mech, 35)
commands, measured = pkmcal.simulate(mech, plan.targets, {"l11": 280.3, "dq3": 0.002}, noise=0.002, seed=1)

# The campaign as exported: a label per pose, the columns in another order.
labels = pd.Index([f"P{i:03d}" for i in range(len(commands))], name="pose")
export = pd.concat(
    [
        pd.DataFrame(measured, columns=["X", "Y"], index=labels),
        pd.DataFrame(commands, columns=mech.actuators, index=labels)[["q3", "q1", "q2"]],
    ],
    axis=1,
)
csv = io.StringIO()
export.to_csv(csv)

# Read back: every column by name, rows matched by their label.
table = pd.read_csv(io.StringIO(csv.getvalue()), index_col="pose")
cal = pkmcal.calibrate(
    mech,
    table[mech.actuators],
    table[["X", "Y"]],
    instrument=pkmcal.Instrument(frame="base", stated_noise=0.002),
    solver=pkmcal.Solver(max_nfev=100),
    validation=pkmcal.Validation(holdout=0.2, seed=3),
)
parameters = cal.to_pandas()
print(parameters.loc[cal.free, ["value", "sd", "unit"]])

# Predictions keep the commands' index: one row per pose label.
predicted = pkmcal.predict(mech, table[mech.actuators], parameters, outputs="x").to_pandas()
errors = predicted[["x", "y"]].to_numpy() - table[["X", "Y"]].to_numpy()
print(f"residual RMS {np.sqrt((errors**2).sum(axis=1).mean()) * 1000:.2f} µm over {len(predicted)} poses")
