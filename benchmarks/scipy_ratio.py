#!/usr/bin/env python3
"""pkmcal against scipy on the Gough-Stewart problem of
benchmarks/gough_stewart_scipy.py, measured in the same run: rounds of one
scipy process (its fit timed in process, five fits, median) then five
pkmcal `calibrate` processes (whole process: reading, identifiability, fit,
covariance, statistics, output), so that load from other work falls on
both alike. Prints both medians and minima and their ratios.

  python3 benchmarks/scipy_ratio.py ROUNDS PYTHON PKMCAL MECHANISM DATA

PYTHON is an interpreter with numpy and scipy; DATA the problem's CSV
(`# frame: base`, sigma_<axis> columns).
"""

import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

SCRIPT = Path(__file__).with_name("gough_stewart_scipy.py")


def scipy_fit_ms(python, mechanism, data):
    out = subprocess.run([python, str(SCRIPT), mechanism, data], capture_output=True,
                         text=True, check=True).stdout
    m = re.search(r"median ([0-9.]+) ms \(min ([0-9.]+)", out)
    return float(m.group(1)), float(m.group(2))


def pkmcal_ms(pkmcal, mechanism, data, out):
    start = time.perf_counter()
    subprocess.run([pkmcal, "calibrate", "--mechanism", mechanism, "--data", data, "--out", out,
                    "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return (time.perf_counter() - start) * 1e3


def main():
    rounds, python, pkmcal, mechanism, data = int(sys.argv[1]), *sys.argv[2:6]
    out = str(Path(data).with_suffix(".ratio.toml"))
    pkmcal_ms(pkmcal, mechanism, data, out)  # warm-up: files in the page cache
    fits, fit_minima, runs = [], [], []
    for _ in range(rounds):
        median, minimum = scipy_fit_ms(python, mechanism, data)
        fits.append(median)
        fit_minima.append(minimum)
        runs += [pkmcal_ms(pkmcal, mechanism, data, out) for _ in range(5)]
    s_med, p_med = statistics.median(fits), statistics.median(runs)
    s_min, p_min = min(fit_minima), min(runs)
    print(f"scipy fit alone:        median {s_med:7.1f} ms  min {s_min:7.1f} ms  ({rounds} processes of 5 fits)")
    print(f"pkmcal whole process:   median {p_med:7.2f} ms  min {p_min:7.2f} ms  ({len(runs)} runs)")
    print(f"pkmcal faster by        {s_med / p_med:.1f}x (medians), {s_min / p_min:.1f}x (minima)")


if __name__ == "__main__":
    main()
