#!/usr/bin/env python3
"""Whole-process timings of two pkmcal builds on the spatial examples and the
built-in hexapods, in one run (medians): calibrate 60 simulated poses (exact
model, default free set), predict 2,000 commands, and `pkmcal klipper` on the
shipped printer.cfg (13 probe points) and on the same printer probed at 50
points (written here with Klipper's delta formulas).

    OLD=/path/to/old/pkmcal [NEW=target/release/pkmcal] python3 benchmarks/spatial-speed.py
"""
import os, statistics, subprocess, sys, tempfile, time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OLD = os.environ.get("OLD") or sys.exit("set OLD to the pkmcal binary of the other build")
NEW = os.environ.get("NEW", os.path.join(ROOT, "target/release/pkmcal"))
EX = os.path.join(ROOT, "examples")


def run(b, args, n=5):
    ts = []
    for _ in range(n):
        a = time.perf_counter()
        subprocess.run([b] + args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        ts.append(time.perf_counter() - a)
    return statistics.median(ts)


os.chdir(tempfile.mkdtemp())
print(f"{'example':26} {'calibrate old':>14} {'new':>9} {'predict old':>12} {'new':>9}")
for ex in ["linear-delta", "linear-delta-4", "rotary-delta", "3-prs",
           "spatial-gough-stewart-6", "gough-stewart-6", "gough-stewart-8"]:
    m = f"{EX}/{ex}/mechanism.toml"
    subprocess.run([NEW, "simulate", "--mechanism", m, "--grid", "60", "--noise", "0.002",
                    "--out", "d.csv", "--quiet"], check=True, stderr=subprocess.DEVNULL)
    subprocess.run([NEW, "simulate", "--mechanism", m, "--grid", "2000", "--out", "p.csv",
                    "--quiet"], check=True, stderr=subprocess.DEVNULL)
    r = []
    for b in (OLD, NEW):
        r.append(run(b, ["calibrate", "--mechanism", m, "--data", "d.csv", "--out", "x.toml", "--quiet"]) * 1e3)
        r.append(run(b, ["predict", "--mechanism", m, "--commands", "p.csv", "--out", "y.csv", "--quiet"], 3) / 2000 * 1e6)
    print(f"{ex:26} {r[0]:11.1f} ms {r[2]:6.1f} ms {r[1]:9.1f} µs {r[3]:6.1f} µs")


def klipper_50(path):
    """The shipped printer.cfg with 50 probe results of its true printer
    (radius 174.9, towers at 210.25° and 329.8°, endstops 297.35, 296.8,
    297.2; 3 µm of noise) on a sunflower of radius 60 mm."""
    import math, random
    random.seed(1)
    radius, arm, angles = 174.9, 333.0, [210.25, 329.8, 90.0]
    endstops, step = [297.35, 296.8, 297.2], 40 / (200 * 16)
    text = open(f"{EX}/klipper-delta/printer.cfg").read().split("#*# [delta_calibrate]")[0]
    text += "#*# [delta_calibrate]\n"
    for k in range(50):
        r, t = 60 * math.sqrt((k + 0.5) / 50), k * 2.39996
        x, y = r * math.cos(t), r * math.sin(t)
        steps = []
        for a, e in zip(angles, endstops):
            tx, ty = radius * math.cos(math.radians(a)), radius * math.sin(math.radians(a))
            h = math.sqrt(arm**2 - (x - tx) ** 2 - (y - ty) ** 2)
            steps.append((e + math.sqrt(arm**2 - radius**2) - h) / step)
        text += f"#*# height{k} = {random.gauss(0, 0.003):.4f}\n"
        text += f"#*# height{k}_pos = {steps[0]:.3f},{steps[1]:.3f},{steps[2]:.3f}\n"
    open(path, "w").write(text)


klipper_50("p50.cfg")
for cfg, label in ((f"{EX}/klipper-delta/printer.cfg", "13 points"), ("p50.cfg", "50 points")):
    for name, b in (("old", OLD), ("new", NEW)):
        t = run(b, ["klipper", "--config", cfg], 11) * 1e3
        print(f"pkmcal klipper, {label} ({name}): {t:.1f} ms")
