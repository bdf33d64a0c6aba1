#!/bin/bash
# Whole-process timings of two builds on the same files (hyperfine means):
# the reference's calibration, Monte Carlo and planning, the 4-RRR's
# calibration, gough-stewart-8's calibration and prediction.
#   OLD=/path/to/other/pkmcal [NEW=…] [HYPERFINE=hyperfine] bash benchmarks/compare-speed.sh
set -eu
ROOT=$(cd "$(dirname "$0")/.." && pwd)
O=${OLD:?set OLD to the pkmcal binary of the other build}
N=${NEW:-$ROOT/target/release/pkmcal}
H=${HYPERFINE:-hyperfine}
E8=$ROOT/examples/gough-stewart-8/mechanism.toml
E4=$ROOT/examples/4-rrr/mechanism.toml
W=$(mktemp -d); trap 'rm -rf "$W"' EXIT; cd "$W"
$N simulate --grid 35 --noise 0.002 --out ref.csv --quiet > /dev/null
$N plan --count 35 --out plan35.csv --quiet > /dev/null
printf 'a1 = 200.3\nb2 = 199.8\ndq1 = 0.001\n' > t4.toml
$N simulate --mechanism $E4 --grid 50 --noise 0.002 --truth t4.toml --out r4.csv --quiet > /dev/null
printf 'a1x = 492.7\nb2z = 0.3\ndL1 = 0.2\n' > t8.toml
$N simulate --mechanism $E8 --grid 60 --noise 0.002 --truth t8.toml --out g8_60.csv --quiet > /dev/null
$N simulate --mechanism $E8 --grid 2000 --out gs8.csv --quiet > /dev/null
run() { echo "== $1"; $H -N -w 2 -r "${R:-10}" "$O ${*:2}" "$N ${*:2}" 2>&1 | grep -E 'Time|faster'; }
run "calibrate reference, 35 poses" calibrate --data ref.csv --out x.toml --quiet
run "montecarlo reference, 200 runs" montecarlo --poses plan35.csv --runs 200 --quiet --out x.csv
run "calibrate 4-rrr, 50 poses" calibrate --mechanism $E4 --data r4.csv --out x.toml --quiet
run "calibrate gough-stewart-8, 60 poses" calibrate --mechanism $E8 --data g8_60.csv --out x.toml --quiet
run "predict gough-stewart-8, 2,000 commands" predict --mechanism $E8 --commands gs8.csv --out x.csv --quiet
R=5 run "plan --count 35, reference" plan --count 35 --out x.csv --quiet
