"""The case study of Jeong & Kim in Python: the planar 2-DOF mechanism with
three actuators, calibrated from 35 measured positions.

Paste it into a notebook cell (the figures then show inline), or run it:

    python examples/python/paper_case_study.py [OUTPUT_DIR]

It plans 35 poses, simulates a machine with errors in its link lengths, joint
positions and encoder offsets measured to 2 µm, calibrates with the exact
model, checks the result on 50 unseen poses, computes corrected commands, and
writes the figures (SVG) and the report into OUTPUT_DIR (default:
pkmcal-case-study).
"""

import pathlib
import sys

import numpy as np

import pkmcal

out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "pkmcal-case-study")

mech = pkmcal.Mechanism()  # the built-in reference mechanism
print(mech)

# The machine as built: a few tenths of a millimetre and a few milliradians
# away from the drawing (mm and rad, the units of every array).
errors = {"l11": 0.35, "l21": -0.2, "B2y": 0.4, "B3x": -0.3, "D2": 0.3, "dq1": 0.004, "dq3": -0.003}
truth = {name: value + errors.get(name, 0.0) for name, value in mech.nominal.items()}

# Where to measure: 35 poses chosen for observability.
plan = pkmcal.plan(mech, 35)
print(f"plan: condition {plan.condition:.1f} (a plain grid: {plan.grid_condition:.1f})")

# The measurements: commands sent, positions read (2 µm noise).
commands, measured = pkmcal.simulate(mech, plan.targets, truth, noise=0.002, seed=7)

# Unseen poses to judge the result.
unseen = pkmcal.plan(mech, 50, spacing=9.0, criterion="O1").targets
v_commands, v_measured = pkmcal.simulate(mech, unseen, truth, noise=0.002, seed=8)

# Simulated positions are in the base frame (a tracker's are not: frame="auto"
# then identifies its frame).
cal = pkmcal.calibrate(
    mech, commands, measured, model="exact", validation=(v_commands, v_measured), frame="base"
)
print(cal)
print(f"{'parameter':>10} {'identified':>14} {'std dev':>10}  unit   true")
for name in cal.free:
    print(
        f"{name:>10} {cal.parameters[name]:14.6f} {cal.std_dev[name]:10.2e}  {cal.units[name]:<5}  {truth[name]:.6f}"
    )
assert cal.validation is not None  # given validation arrays, there is one
before, after = cal.validation
print(f"unseen poses: max error {before.distance_max:.3f} mm before, {after.distance_max:.4f} mm after")
for w in cal.warnings:
    print("warning:", w)

# Corrected commands for the controller: the calibrated model inverted.
comp = pkmcal.compensate(mech, unseen, cal)
reached = pkmcal.predict(mech, comp.commands, truth).x
print(f"corrected commands reach the targets within {np.max(np.linalg.norm(reached - unseen, axis=1)) * 1e3:.2f} µm")

# Figures: inline in a notebook (each has _repr_svg_), files here.
out.mkdir(parents=True, exist_ok=True)
for fig in cal.figures():
    fig.save(out / f"{fig.name}.svg")
cal.save_report(out / "report")
(out / "identified.toml").write_text(cal.to_toml())
print(f"figures, report and parameters -> {out}")
