#!/usr/bin/env bash
# Where the genetic search beats its heuristic seed: swarm study selection --genetic-gain over
# localizer x motion noise (x 1, x 3) x body radius (0.011 m, 0) x swarm size (10, 30, 100).
# Usage: tools/genetic_gain.sh LOCALIZER [OUT_DIR]; one JSON line per cell in OUT_DIR/LOCALIZER.jsonl
# (docs/selection.md tabulates them). Configurations per size: 8 (n_r = 10), 4 (30), 2 (100).
set -euo pipefail
localizer=${1:?localizer}
out=${2:-docs/data/genetic-gain}
mkdir -p "$out"
for size_configs in 10:8 30:4 100:2; do
  robots=${size_configs%%:*}; configs=${size_configs##*:}
  for noise in "" "--turn-sigma-deg 9 --drive-sigma-frac 0.15"; do
    for radius in 0.011 0; do
      # shellcheck disable=SC2086 # $noise holds two flags
      swarm study selection --genetic-gain --robots "$robots" --configs "$configs" --eval-samples 256 --seed 0 \
        --localizer "$localizer" --robot-radius "$radius" $noise --json | tail -n 1 >> "$out/$localizer.jsonl"
    done
  done
done
