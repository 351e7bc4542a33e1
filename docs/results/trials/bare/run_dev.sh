#!/usr/bin/env bash
# The long preset without the keep-out term and the fade near the goal ("bare"), against the
# long preset, with the pose model on the dev sets (--seed 1, 50 trials a scenario, run on to
# 1 cm and 5 deg). One queue of one worker. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/bare
export OMP_NUM_THREADS=1
BARE=(--set cost.w_keepout=0 --set cost.near_goal_m=0)
run() { se3push trials --n 50 --seed 1 --workers 1 --tolerance precise --preset long "$@"; }
for s in single_box multi_object heldout_objects; do
    run --scenario $s --model pose --out "$D/dev_pose_long_$s"
    run --scenario $s --model pose "${BARE[@]}" --out "$D/dev_pose_bare_$s"
done
