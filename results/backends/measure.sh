#!/usr/bin/env bash
# Which env backend when, on the CPU: the same short far-box run (3 joints, 5 seeds in one
# process, 60 episodes: 20 warm-up, 40 with their 100 updates each, 3 test sessions of 20
# episodes per seed, one torch thread) under each backend, alternating, ROUNDS rounds; prints
# one line per run: round, backend, user+system CPU seconds, wall seconds.
#   bash results/backends/measure.sh 2 > results/backends/cpu_seconds.txt
set -euo pipefail
rounds=${1:-2}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for round in $(seq "$rounds"); do
  for backend in numpy batched program; do
    /usr/bin/time -f "$round $backend %U %S %e" -o "$tmp/time" \
      python -m ddpg_her.train --region farbox --joints 3 --seeds 0 1 2 3 4 --episodes 60 \
      --warmup-episodes 20 --eval-every 20 --eval-episodes 20 --threads 1 --no-progress \
      --no-tensorboard --env-backend "$backend" --out "$tmp/$round-$backend/s{seed}" >/dev/null
    awk '{printf "%s %s cpu_s=%.1f wall_s=%.1f\n", $1, $2, $3 + $4, $5}' "$tmp/time"
  done
done
