#!/usr/bin/env bash
# The trained objects on the fresh seed with the long preset too (--seed 11, 50 trials, run on
# to 1 cm and 5 deg): single_box and multi_object with the pose model and the simulator, so
# that both have both plans on all three scenarios of this set. One queue of one worker. Run
# from the repository's root.
set -euo pipefail
D=docs/results/trials/pose
export OMP_NUM_THREADS=1
run() { se3push trials --n 50 --seed 11 --workers 1 --tolerance precise --preset long "$@"; }
for s in single_box multi_object; do run --scenario $s --model pose --out "$D/s11_pose_long_$s"; done
for s in single_box multi_object; do run --scenario $s --model oracle --out "$D/s11_oracle_long_$s"; done
