#!/usr/bin/env bash
# Each of the two other-seed generalists alone (the ensemble's members besides the shipped
# model), the default and the long preset, on the dev sets (seed 1, 20 trials), two runs side
# by side, one worker each. Is the long plan's loss the shipped checkpoint's, or the recipe's?
set -euo pipefail
D=docs/results/trials/ensemble
export OMP_NUM_THREADS=1
run() { scenario=$1; name=$2; shift 2; se3push trials --scenario "$scenario" --n 20 --seed 1 --workers 1 "$@" --out "$D/$name"; }
for s in 1 2; do
  M=runs/gen_s2_seed$s/best.pt
  run heldout_objects dev_seed${s}_default --model $M &
  run multi_object dev_seed${s}_default_multi_object --model $M &
  wait
  run heldout_objects dev_seed${s}_long --model $M --preset long &
  run multi_object dev_seed${s}_long_multi_object --model $M --preset long &
  wait
done
