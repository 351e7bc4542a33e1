#!/usr/bin/env bash
# The shipped pose model (se3net/weights/pose.pt, `se3push train --variant pose`: docs/model.md)
# on trial set 2 (--seed 0, 50 trials per scenario, run on to 1 cm and 5 deg), with the default
# and the long preset: paired with the shipped SE3-Net's and the simulator's
# headline/*_surface_* (default) and headline/*_h12_* (long) folders (compare.sh).
# Two queues of one worker each, side by side. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pose
export OMP_NUM_THREADS=1
run() { se3push trials --n 50 --seed 0 --workers 1 --tolerance precise --model pose "$@"; }
queue() {
    for sc in single_box multi_object heldout_objects; do
        run --scenario "$sc" --preset "$1" --out "$D/${1}_$sc"
    done
}
queue default &
queue long &
wait
