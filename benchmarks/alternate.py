#!/usr/bin/env python3
"""Whole-process timings of commands run in turn (A, B, A, B, ...), so that a
burst of load from other work on a shared machine falls on all of them alike;
prints each command's median, quartiles and minimum (ms). Interference only
adds time: the minimum estimates the uncontended cost, the median the usual.

  python3 benchmarks/alternate.py ROUNDS 'CMD_A' 'CMD_B' ...

A command may start with VAR=value words (environment variables).
"""

import os
import shlex
import statistics
import subprocess
import sys
import time


def run(command):
    words = shlex.split(command)
    env = dict(os.environ)
    while words and "=" in words[0] and not words[0].startswith(("/", ".")):
        key, value = words.pop(0).split("=", 1)
        env[key] = value
    start = time.perf_counter()
    subprocess.run(words, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, check=True)
    return (time.perf_counter() - start) * 1e3


def main():
    rounds = int(sys.argv[1])
    commands = sys.argv[2:]
    for c in commands:  # warm-up: files in the page cache
        run(c)
    times = [[] for _ in commands]
    for _ in range(rounds):
        for k, c in enumerate(commands):
            times[k].append(run(c))
    for c, t in zip(commands, times):
        q = statistics.quantiles(t, n=4)
        print(f"median {statistics.median(t):8.2f}  q1 {q[0]:8.2f}  q3 {q[2]:8.2f}  min {min(t):8.2f}  {c}")


if __name__ == "__main__":
    main()
