#!/bin/bash
# Compare calibrations and predictions of two builds on every shipped example
# (40 simulated poses each): identified parameters and predictions, max
# differences, and the calibration's wall time. Exits 1 when any parameter
# file or prediction differs by a single byte (a change meant to be bit for
# bit the same must pass it).
#   OLD=/path/to/other/pkmcal bash benchmarks/compare-builds.sh
set -u
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OLD=${OLD:?set OLD to the pkmcal binary of the other build}
NEW=${NEW:-$ROOT/target/release/pkmcal}
EX=$ROOT/examples
W=$(mktemp -d); trap 'rm -rf "$W"' EXIT; cd "$W"
status=0
for ex in jeong-kim-2dof jeong-kim-planar five-bar 3-rrr 4-rrr gough-stewart-6 gough-stewart-8 linear-delta linear-delta-4 rotary-delta 3-prs spatial-gough-stewart-6; do
  M=$EX/$ex/mechanism.toml
  printf '' > t.toml
  $NEW simulate --mechanism $M --grid 40 --noise 0.002 --out $ex.csv --quiet 2>/dev/null
  $NEW montecarlo --mechanism $M --poses $ex.csv --runs 1 --out mc.csv --quiet >/dev/null 2>&1
  for b in OLD NEW; do
    B=${!b}
    s=$(date +%s.%N)
    $B calibrate --mechanism $M --data $ex.csv --out $ex.$b.toml --quiet > /dev/null 2>&1
    e=$(date +%s.%N)
    $B predict --mechanism $M --params $ex.$b.toml --commands $ex.csv --out $ex.$b.pred.csv 2>/dev/null
    printf "%s %s cal %.3fs\n" $ex $b $(echo "$e - $s" | bc)
  done
  python3 - $ex <<'PY'
import sys,csv
ex=sys.argv[1]
def params(f): return [float(l.split('=')[1].split('#')[0]) for l in open(f) if '=' in l and not l.startswith('#')]
a,b=params(f'{ex}.OLD.toml'),params(f'{ex}.NEW.toml')
def pred(f):
    rows=list(csv.DictReader(l for l in open(f) if not l.startswith('#')))
    return [[float(r[k]) for k in r if k in ('x','y','z','rx','ry','rz','phi')] for r in rows]
pa,pb=pred(f'{ex}.OLD.pred.csv'),pred(f'{ex}.NEW.pred.csv')
print(f"  {ex}: params max diff {max(abs(x-y) for x,y in zip(a,b)):.2e}; predictions max diff {max(abs(x-y) for r,s in zip(pa,pb) for x,y in zip(r,s)):.2e}")
PY
  for f in toml pred.csv; do
    if ! cmp -s $ex.OLD.$f $ex.NEW.$f || [ ! -s $ex.NEW.$f ]; then echo "  $ex: $f DIFFERENT"; status=1; fi
  done
done
exit $status
