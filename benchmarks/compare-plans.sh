#!/bin/bash
# Plans of two builds on the reference and every shipped example, under each
# criterion: the plan files must be byte for byte the same; prints the wall
# time of each.
#   OLD=/path/to/other/pkmcal [NEW=…] [COUNT=40] bash benchmarks/compare-plans.sh
set -u
ROOT=$(cd "$(dirname "$0")/.." && pwd)
OLD=${OLD:?set OLD to the pkmcal binary of the other build}
NEW=${NEW:-$ROOT/target/release/pkmcal}
COUNT=${COUNT:-40}
W=$(mktemp -d); trap 'rm -rf "$W"' EXIT; cd "$W"
status=0
for ex in reference $ROOT/examples/*/mechanism.toml; do
  if [ "$ex" = reference ]; then name=reference; mech=(); else name=$(basename "$(dirname "$ex")"); mech=(--mechanism "$ex"); fi
  for cr in O1 O3 O5; do
    s0=$(date +%s%N)
    "$OLD" plan "${mech[@]}" --count "$COUNT" --criterion $cr --quiet --out old.csv > /dev/null 2>&1
    s1=$(date +%s%N)
    "$NEW" plan "${mech[@]}" --count "$COUNT" --criterion $cr --quiet --out new.csv > /dev/null 2>&1
    s2=$(date +%s%N)
    if cmp -s old.csv new.csv; then r=same; else r=DIFFERENT; status=1; fi
    printf "%-24s %s %-9s old %6d ms  new %6d ms\n" "$name" $cr $r $(( (s1 - s0) / 1000000 )) $(( (s2 - s1) / 1000000 ))
  done
done
exit $status
