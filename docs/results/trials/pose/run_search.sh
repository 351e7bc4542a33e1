#!/usr/bin/env bash
# The pose model with four times the default search (--set optimiser.samples=128: CEM's first
# iteration samples 128 sequences instead of 32), the default and the long planner: the dev
# sets (--seed 1), then the default on trial set 2 and on the seed-11 held-out set.
# Two queues of one worker each, side by side. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pose
export OMP_NUM_THREADS=1
run() { se3push trials --n 50 --workers 1 --model pose --set optimiser.samples=128 "$@"; }
queue() {
    for sc in single_box multi_object heldout_objects; do
        run --scenario "$sc" --seed 1 --preset "$1" --out "$D/dev_s128_${1}_$sc"
    done
}
queue default &
queue long &
wait
set2() { run --scenario "$1" --seed 0 --tolerance precise --out "$D/s128_default_$1"; }
set2 single_box &
set2 multi_object &
wait
set2 heldout_objects &
run --scenario heldout_objects --seed 11 --tolerance precise --out "$D/s11_s128_default" &
wait
