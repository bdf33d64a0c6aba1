#!/bin/bash
# Median wall time (ms, of 5 runs) of `calibrate` on 40 simulated poses of
# several shipped examples, for two builds, each reading its own example
# files (a build before a renaming of parameters cannot read the renamed
# files: give it the examples of its own commit).
#   OLD=/path/to/other/pkmcal OLD_EXAMPLES=/path/to/its/examples [NEW=…] bash benchmarks/compare-calibrate-times.sh
set -u
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OLD=${OLD:?set OLD to the pkmcal binary of the other build}
OLD_EXAMPLES=${OLD_EXAMPLES:-$ROOT/examples}
NEW=${NEW:-$ROOT/target/release/pkmcal}
W=$(mktemp -d); trap 'rm -rf "$W"' EXIT; cd "$W"
for ex in jeong-kim-2dof five-bar gough-stewart-6 gough-stewart-8 linear-delta rotary-delta 3-prs; do
  "$NEW" simulate --mechanism "$ROOT/examples/$ex/mechanism.toml" --grid 40 --noise 0.002 --out d.csv --quiet 2>/dev/null
  for b in OLD NEW; do
    B=${!b}
    if [ $b = OLD ]; then M=$OLD_EXAMPLES/$ex/mechanism.toml; else M=$ROOT/examples/$ex/mechanism.toml; fi
    ts=()
    for _ in 1 2 3 4 5; do
      s=$(date +%s%N); "$B" calibrate --mechanism "$M" --data d.csv --out p.toml --quiet >/dev/null 2>&1; e=$(date +%s%N)
      ts+=($(( (e - s) / 1000000 )))
    done
    printf "%-16s %s %5d ms\n" "$ex" $b "$(printf "%s\n" "${ts[@]}" | sort -n | sed -n 3p)"
  done
done
