#!/usr/bin/env python3
"""Whole-process timings of two pkmcal builds on the spatial examples and the
built-in hexapod, in one run (medians): calibrate 60 simulated poses (exact
model, default free set), predict 2,000 commands, and `pkmcal klipper` on the
shipped printer.cfg.

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
           "spatial-gough-stewart-6", "gough-stewart-6"]:
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
for name, b in (("old", OLD), ("new", NEW)):
    t = run(b, ["klipper", "--config", f"{EX}/klipper-delta/printer.cfg"], 11) * 1e3
    print(f"pkmcal klipper ({name}): {t:.1f} ms")
