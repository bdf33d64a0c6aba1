#!/bin/bash
# A fresh clone's first builds, as a new user runs them: in an empty target
# directory, the demo's build (what `cargo run -- demo` compiles), then the
# tests' build (`cargo test --workspace --no-run`): wall times and the units
# the second compiles (only dev-dependencies and tests when nothing the
# demo built is rebuilt).
#   bash benchmarks/setup-builds.sh [TARGET_DIR]
set -u
ROOT=$(cd "$(dirname "$0")/.." && pwd)
T=${1:-$(mktemp -d)}
cd "$ROOT"
unset CARGO_PROFILE_DEV_DEBUG
rm -rf "$T"
LOG=$(mktemp)
s=$(date +%s); CARGO_TARGET_DIR=$T cargo build --quiet; e=$(date +%s)
echo "demo build $((e - s)) s"
s=$(date +%s); CARGO_TARGET_DIR=$T cargo test --workspace --no-run 2> "$LOG"; e=$(date +%s)
echo "test build $((e - s)) s, units compiled: $(grep -c '^ *Compiling' "$LOG")"
grep '^ *Compiling' "$LOG" | awk '{print $2}' | tr '\n' ' '; echo
rm -f "$LOG"
