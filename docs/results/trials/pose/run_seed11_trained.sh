#!/usr/bin/env bash
# The trained objects on the fresh seed too (--seed 11, 50 trials, run on to 1 cm and 5 deg):
# single_box and multi_object with the pose model, the shipped SE3-Net and the simulator, the
# default planner. Two queues of one worker each, side by side. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pose
export OMP_NUM_THREADS=1
run() { se3push trials --n 50 --seed 11 --workers 1 --tolerance precise "$@"; }
queue() {
    run --scenario "$1" --model pose --out "$D/s11_pose_default_$1"
    run --scenario "$1" --model default --out "$D/s11_se3net_default_$1"
    run --scenario "$1" --model oracle --out "$D/s11_oracle_default_$1"
}
queue single_box &
queue multi_object &
wait
