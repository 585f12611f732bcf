#!/usr/bin/env bash
# The pre-registered runs of the Monte Carlo readings (docs/experiments.md): one `swarm compare`
# per cell, in priority order, each cell's JSON summary appended to $OUT/cells.jsonl as it ends
# and its per-trajectory rows kept in $OUT/<cell>/runs.csv (partial results survive an interrupt).
# Run it from the repository's root (it runs that folder's code: python -m swarm_cli.main).
# Usage: tools/mc_readings.sh [OUT (default out/mc-readings)] [WORKERS (default 2)] [LOCALIZER (joint|paper; default both)]
# Several runners may share one OUT: each takes a cell by creating $OUT/<cell>.lock.
set -u
OUT=${1:-out/mc-readings}
WORKERS=${2:-2}
ONLY=${3:-}
mkdir -p "$OUT"
noise() {  # localizer, level -> model flags (calibrated: swarm study calibration's motion scale, sensing default)
  case "$1:$2" in
    paper:calibrated) echo "--turn-sigma-deg 12.78 --drive-sigma-frac 0.213" ;;  # 3 deg, 0.05 x 4.26
    joint:calibrated) echo "--turn-sigma-deg 16.74 --drive-sigma-frac 0.279" ;;  # 3 deg, 0.05 x 5.58
    *:default) echo "" ;;
  esac
}
reading() {  # R0..R3 -> selection flags
  case "$1" in
    R0) echo "--mc-start estimate --mc-emax mean" ;;
    R1) echo "--mc-start known --mc-emax mean" ;;
    R2) echo "--mc-start estimate --mc-emax worst" ;;
    R3) echo "--mc-start known --mc-emax worst" ;;
  esac
}
cells() {  # priority: calibrated noise R0/R1, then default noise R0/R1, then R2/R3
  for level in calibrated default; do for r in R0 R1; do for loc in joint paper; do for seed in 0 1000; do
    echo "$r $loc $level $seed"; done; done; done; done
  for level in calibrated default; do for r in R2 R3; do for loc in joint paper; do for seed in 0 1000; do
    echo "$r $loc $level $seed"; done; done; done; done
}
cells | while read -r r loc level seed; do
  name="$r-$loc-$level-$seed"
  [ -n "$ONLY" ] && [ "$loc" != "$ONLY" ] && continue
  grep -q "\"cell\":\"$name\"" "$OUT/cells.jsonl" 2>/dev/null && continue
  mkdir "$OUT/$name.lock" 2>/dev/null || continue
  cmd="swarm compare --trajectories 30 --configs 8 --robots 10 --methods inchworm,ref57 --seed $seed --localizer $loc $(noise "$loc" "$level") $(reading "$r") --robot-radius 0 --workers $WORKERS --out $OUT/$name --json"
  python -m swarm_cli.main compare --help | grep -q -- --robot-radius || cmd=${cmd/--robot-radius 0 /}  # point robots are the only kind before the collision constraint
  start=$(date +%s)
  json=$(nice -n 10 python -m swarm_cli.main ${cmd#swarm } 2>"$OUT/$name.err" | tail -n 1)  # the code of the current folder
  case "$json" in
    "{"*) echo "{\"cell\":\"$name\",\"reading\":\"$r\",\"localizer\":\"$loc\",\"noise\":\"$level\",\"seed\":$seed,\"wall_s\":$(( $(date +%s) - start )),\"command\":\"$cmd\",\"summary\":$json}" >> "$OUT/cells.jsonl" ;;
    *) echo "cell $name failed: see $OUT/$name.err" >&2; rmdir "$OUT/$name.lock" ;;
  esac
done
