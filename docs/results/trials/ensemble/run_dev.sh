#!/usr/bin/env bash
# The shipped model and two generalists trained by the same command with other seeds, as an
# ensemble whose disagreement the cost penalises (cost.w_spread 1, the default), planning with
# the long preset on the dev sets (seed 1, 20 trials), one worker each, two runs side by side.
# The members: se3push train --data data/household data/single_box --variant se3net --k 6
#   --stride 2 --iters 15000 --keep-every 5000 --seed S --out runs/gen_s2_seedS   (S = 1, 2)
set -euo pipefail
D=docs/results/trials/ensemble
E=default+runs/gen_s2_seed1/best.pt+runs/gen_s2_seed2/best.pt
export OMP_NUM_THREADS=1
run() { scenario=$1; name=$2; shift 2; se3push trials --scenario "$scenario" --n 20 --seed 1 --workers 1 "$@" --out "$D/$name"; }
run heldout_objects dev_ens3_long --model "$E" --preset long &
run multi_object dev_ens3_long_multi_object --model "$E" --preset long &
wait
