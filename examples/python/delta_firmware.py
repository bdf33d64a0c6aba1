"""A delta printer's firmware calibrated from Python: the Klipper example's
probe results fitted as Klipper fits them, then the printer as built
(``physical=True``) with the probe's σ stated, the values to write and the
verdict read as data; then the Marlin example with Marlin's own G33 run on
the printer the fit found, compared with pkmcal's values.

    python examples/python/delta_firmware.py [printer.cfg]

Nothing is written: ``out=``, ``height_map=`` and ``report_dir=`` would
write the new configuration, a ``[bed_mesh]`` profile and the owner's
report, as ``pkmcal klipper --out --height-map --report-dir`` does.
"""

import pathlib
import sys

import pkmcal

here = pathlib.Path(__file__).resolve().parent
config = sys.argv[1] if len(sys.argv) > 1 else str(here.parent / "klipper-delta" / "printer.cfg")

own = pkmcal.klipper(config)
print(f"Klipper's own fit: {own.termination}; height RMS {own.height_errors['after'].rms:.4f} mm")
for v in own.values:
    sigma = "fixed" if v.sigma is None else f"{v.sigma:.4f} {v.unit}"
    print(f"  {v.name:<28} {v.before:>12.4f} -> {v.after:>12.4f}  σ {sigma}")

built = pkmcal.klipper(config, physical=True, probe_noise=0.005)
verdict = built.physical
assert verdict is not None
which = "the values for the nozzle" if verdict.projection_written else "Klipper's own fit"
print(f"\nas built (probe σ {verdict.probe_noise} mm, stated: {verdict.probe_noise_stated}): {which} written")
for name, e in verdict.nozzle_errors.items():
    print(f"  nozzle error with {name:<9} XY RMS {e.xy_rms:.4f} mm, Z RMS {e.z_rms:.4f} mm")
for cube in verdict.cubes:
    x, y = cube.centre
    print(f"  20 mm cube at ({x:.0f}, {y:.0f}): X {cube.size[0]:+.3f} ± {cube.size_sd[0]:.3f} mm")
if verdict.next_measurements:
    best = verdict.next_measurements[0]
    print(f"  next: {best.what} (largest σ {best.largest_before:.3f} -> {best.largest_after:.3f} mm)")
if verdict.noise_note is not None:
    print(f"  {verdict.noise_note.message}")
for w in built.warnings:
    print(f"warning: {w.message}\n  hint: {w.hint}")

marlin = here.parent / "marlin-delta"
m = pkmcal.marlin(marlin / "M503.txt", marlin / "G30.log")
g33 = m.g33
assert g33 is not None
if g33.run is None:
    print(f"\nG33 not run: {g33.not_run}")
else:
    run = g33.run
    print(f"\nMarlin's G33 P{g33.points} at radius {g33.radius:.2f} mm ({g33.radius_from}), {len(run.std_devs)} iterations, would set:")
    for line in run.settings.splitlines():
        print(f"  {line}")
    print(f"  height RMS at the probed points: G33's {run.with_g33.rms:.4f} mm, pkmcal's {run.with_pkmcal.rms:.4f} mm")
