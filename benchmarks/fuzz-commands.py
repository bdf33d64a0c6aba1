#!/usr/bin/env python3
"""Whole-command fuzzing (issue 34): RUNS runs of pkmcal subcommands, each on
one mutated input file, under a memory limit (address space, LIMIT_MB), with
a time limit (TIMEOUT seconds). A run fails when it

* exits other than 0, 1 (a file's contents or the computation) or 2 (the
  command line), or is killed by a signal (an abort on allocation failure, a
  panic's exit 101);
* prints "panicked" on standard error;
* changes any of its input files;
* leaves any new file behind when it exits non-zero.

Inputs are made first with the binary itself (simulated data, a calibration,
a G-code program, a RepRapFirmware and a Klipper configuration with probe
results) and copied into a fresh directory for each run; the mutation is one
of: byte edits, a truncation, a duplicated or deleted line, a number replaced
by an extreme one (1e308, -1e308, nan, inf, 1e-320, 0, -0, 1e15), a swapped
pair of columns. Seeded: the same SEED gives the same runs.

  PKMCAL=target/release/pkmcal RUNS=10000 SEED=1 python3 benchmarks/fuzz-commands.py
"""

import hashlib
import os
import random
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.abspath(os.environ.get("PKMCAL", os.path.join(ROOT, "target/release/pkmcal")))
RUNS = int(os.environ.get("RUNS", "10000"))
SEED = int(os.environ.get("SEED", "1"))
LIMIT_MB = int(os.environ.get("LIMIT_MB", "1024"))
TIMEOUT = float(os.environ.get("TIMEOUT", "120"))
EXTREMES = ["1e308", "-1e308", "nan", "inf", "-inf", "1e-320", "0", "-0", "1e15", ""]


def pk(args, cwd):
    r = subprocess.run([BIN, *args, "--quiet"], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"making the inputs: pkmcal {' '.join(args)}: {r.stderr}")


def make_inputs(base):
    ex = os.path.join(ROOT, "examples")
    for name in ["five-bar", "linear-delta", "gough-stewart-6"]:
        shutil.copy(os.path.join(ex, name, "mechanism.toml"), os.path.join(base, f"{name}.toml"))
    with open(os.path.join(base, "truth.toml"), "w") as f:
        f.write("l11 = 280.4\nB3x = 149.6\ndq1 = 0.001\ndq3 = -0.0012\nD2 = 215.2\n")
    with open(os.path.join(base, "setup.toml"), "w") as f:
        f.write("bar_offset = 0.0\nsockets = [[-250.0, -60.0], [260.0, -40.0], [20.0, 480.0]]\n")
    pk(["simulate", "--truth", "truth.toml", "--grid", "16", "--noise", "0.002", "--out", "data.csv"], base)
    pk(["simulate", "--truth", "truth.toml", "--grid", "12", "--setup", "setup.toml", "--out", "bb.csv"], base)
    pk(["calibrate", "--data", "data.csv", "--out", "cal.toml"], base)
    for name in ["five-bar", "linear-delta", "gough-stewart-6"]:
        pk(["simulate", "--mechanism", f"{name}.toml", "--grid", "10", "--noise", "0.002", "--out", f"{name}.csv"], base)
    with open(os.path.join(base, "targets.csv"), "w") as f:
        f.write("target_x,target_y\n0,180\n40,120\n-60,230\n10,200\n")
    with open(os.path.join(base, "part.gcode"), "w") as f:
        f.write("; part\nG21\nG90\nM83\nG0 X-20 Y180 F6000 ; start\nG1 X20 E1.5 F1200\nG1 Y220 E1.5\nG91\nG1 X-40 E1.5\nG90\nG1 Y180\nM2\n")
    with open(os.path.join(base, "config.g"), "w") as f:
        f.write("; delta\nM665 L360 R190 H420 B150 X0 Y0 Z0 ; geometry\nM666 X0 Y0 Z0 A0 B0\n")
    with open(os.path.join(base, "probes.csv"), "w") as f:
        f.write("x,y,z\n0,0,0.05\n")
        for k in range(16):
            r = 60 if k < 8 else 120
            a = 0.785398 * k + 0.3
            f.write(f"{r * __import__('math').cos(a):.3f},{r * __import__('math').sin(a):.3f},{0.02 * ((k * 7) % 5 - 2):.4f}\n")
    shutil.copy(os.path.join(ex, "klipper-delta", "printer.cfg"), os.path.join(base, "printer.cfg"))


# (command line, the file mutated): every input of each command is mutated in
# some scenario.
SCENARIOS = [
    (["predict", "--params", "cal.toml", "--commands", "data.csv", "--out", "o.csv"], "data.csv"),
    (["predict", "--params", "cal.toml", "--commands", "data.csv", "--out", "o.csv"], "cal.toml"),
    (["calibrate", "--data", "data.csv", "--out", "p.toml", "--report", "r.json"], "data.csv"),
    (["calibrate", "--mechanism", "five-bar.toml", "--data", "five-bar.csv", "--out", "p.toml"], "five-bar.toml"),
    (["calibrate", "--mechanism", "five-bar.toml", "--data", "five-bar.csv", "--out", "p.toml"], "five-bar.csv"),
    (["calibrate", "--mechanism", "linear-delta.toml", "--data", "linear-delta.csv", "--out", "p.toml"], "linear-delta.csv"),
    (["calibrate", "--mechanism", "gough-stewart-6.toml", "--data", "gough-stewart-6.csv", "--out", "p.toml"], "gough-stewart-6.toml"),
    (["analyze", "--data", "data.csv", "--report", "a.json"], "data.csv"),
    (["simulate", "--truth", "truth.toml", "--targets", "targets.csv", "--out", "s.csv"], "truth.toml"),
    (["simulate", "--truth", "truth.toml", "--targets", "targets.csv", "--out", "s.csv"], "targets.csv"),
    (["simulate", "--mechanism", "linear-delta.toml", "--grid", "6", "--out", "s.csv"], "linear-delta.toml"),
    (["compensate", "--params", "cal.toml", "--targets", "targets.csv", "--out", "c.csv"], "targets.csv"),
    (["compensate", "--params", "cal.toml", "--targets", "targets.csv", "--cartesian", "--out", "c.csv"], "cal.toml"),
    (["gcode", "--params", "cal.toml", "--in", "part.gcode", "--out", "o.gcode"], "part.gcode"),
    (["gcode", "--params", "cal.toml", "--in", "part.gcode", "--dialect", "reprap", "--max-segment", "5", "--out", "o.gcode"], "part.gcode"),
    (["reprap", "--config", "config.g", "--probes", "probes.csv", "--out", "new.g"], "config.g"),
    (["reprap", "--config", "config.g", "--probes", "probes.csv", "--out", "new.g"], "probes.csv"),
    (["klipper", "--config", "printer.cfg", "--out", "new.cfg"], "printer.cfg"),
    (["trilaterate", "--setup", "setup.toml", "--data", "bb.csv", "--out", "tri.csv"], "bb.csv"),
    (["trilaterate", "--setup", "setup.toml", "--data", "bb.csv", "--out", "tri.csv"], "setup.toml"),
    (["plan", "--count", "12", "--max-candidates", "200", "--out", "plan.csv"], None),
    (["plan", "--mechanism", "five-bar.toml", "--count", "12", "--max-candidates", "200", "--out", "plan.csv"], "five-bar.toml"),
    (["montecarlo", "--poses", "data.csv", "--runs", "3", "--validation", "5", "--out", "mc.csv"], "data.csv"),
    (["parameters", "--mechanism", "gough-stewart-6.toml", "--json"], "gough-stewart-6.toml"),
]


def mutate(text, rng):
    kind = rng.randrange(6)
    b = bytearray(text)
    if kind == 0 and b:  # byte edits
        for _ in range(rng.randint(1, 8)):
            p = rng.randrange(len(b) + 1)
            if rng.random() < 0.5 and p < len(b):
                del b[p]
            else:
                b.insert(p, rng.randrange(256))
        return bytes(b)
    if kind == 1:  # truncation
        return bytes(b[: rng.randrange(len(b) + 1)])
    lines = bytes(b).split(b"\n")
    if kind == 2 and lines:  # a duplicated or deleted line
        k = rng.randrange(len(lines))
        if rng.random() < 0.5:
            lines.insert(k, lines[k])
        else:
            del lines[k]
        return b"\n".join(lines)
    if kind == 3:  # an extreme number
        s = bytes(b).decode("utf-8", "replace")
        nums = list(re.finditer(r"-?\d+(\.\d+)?(e-?\d+)?", s))
        if nums:
            m = rng.choice(nums)
            s = s[: m.start()] + rng.choice(EXTREMES) + s[m.end():]
        return s.encode()
    if kind == 4 and len(lines) > 1:  # swapped columns
        rows = [l.split(b",") for l in lines]
        n = len(rows[0])
        if n > 1:
            i, j = rng.sample(range(n), 2)
            for r in rows:
                if len(r) > max(i, j):
                    r[i], r[j] = r[j], r[i]
            return b"\n".join(b",".join(r) for r in rows)
    # random bytes appended
    return bytes(b) + bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))


def digest(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def limit():
    lim = LIMIT_MB << 20
    resource.setrlimit(resource.RLIMIT_AS, (lim, lim))


def main():
    rng = random.Random(SEED)
    base = tempfile.mkdtemp(prefix="pkmcal-fuzz-base-")
    make_inputs(base)
    failures, codes, start = [], {}, time.time()
    slowest = (0.0, None)
    for run in range(RUNS):
        args, target = SCENARIOS[rng.randrange(len(SCENARIOS))]
        d = tempfile.mkdtemp(prefix="pkmcal-fuzz-")
        for f in os.listdir(base):
            shutil.copy(os.path.join(base, f), d)
        if target:
            p = os.path.join(d, target)
            with open(p, "rb") as f:
                text = f.read()
            with open(p, "wb") as f:
                f.write(mutate(text, rng))
        before = {f: digest(os.path.join(d, f)) for f in os.listdir(d)}
        t0 = time.time()
        try:
            r = subprocess.run([BIN, *args, "--quiet"], cwd=d, capture_output=True, preexec_fn=limit, timeout=TIMEOUT)
            code, err = r.returncode, r.stderr.decode("utf-8", "replace")
        except subprocess.TimeoutExpired:
            code, err = "timeout", ""
        took = time.time() - t0
        if took > slowest[0]:
            slowest = (took, " ".join(args))
        codes[code] = codes.get(code, 0) + 1
        why = []
        if code not in (0, 1, 2):
            why.append(f"exit {code}")
        if "panicked" in err:
            why.append("panic")
        after = set(os.listdir(d))
        changed = [f for f, h in before.items() if f not in after or digest(os.path.join(d, f)) != h]
        if changed:
            why.append(f"inputs changed: {changed}")
        if code != 0 and after - set(before):
            why.append(f"files left by a failed run: {sorted(after - set(before))}")
        if why:
            keep = os.path.join(tempfile.gettempdir(), f"pkmcal-fuzz-failure-{SEED}-{run}")
            shutil.copytree(d, keep, dirs_exist_ok=True)
            failures.append((run, " ".join(args), target, why, err.strip().splitlines()[-1:] if err else [], keep))
        shutil.rmtree(d, ignore_errors=True)
        if (run + 1) % 500 == 0:
            print(f"{run + 1} runs, {len(failures)} failures, {time.time() - start:.0f} s", file=sys.stderr, flush=True)
    shutil.rmtree(base, ignore_errors=True)
    print(f"runs {RUNS}, seed {SEED}, memory limit {LIMIT_MB} MiB, {time.time() - start:.0f} s")
    print("exit codes: " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items(), key=str)))
    print(f"slowest run: {slowest[0]:.2f} s ({slowest[1]})")
    print(f"failures: {len(failures)}")
    for f in failures[:50]:
        print("  ", f)
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
