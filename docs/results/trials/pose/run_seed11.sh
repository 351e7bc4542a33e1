#!/usr/bin/env bash
# A fresh held-out set (--seed 11, 50 trials, run on to 1 cm and 5 deg; no earlier run used it):
# the pose model, the shipped SE3-Net and the simulator, each with the default and the long
# preset. Two queues of one worker each, side by side. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pose
export OMP_NUM_THREADS=1
run() {
    se3push trials --scenario heldout_objects --n 50 --seed 11 --workers 1 --tolerance precise "$@"
}
{ run --model pose --out "$D/s11_pose_default"
  run --model pose --preset long --out "$D/s11_pose_long"
  run --model default --out "$D/s11_se3net_default"
  run --model default --preset long --out "$D/s11_se3net_long"; } &
{ run --model oracle --out "$D/s11_oracle_default"
  run --model oracle --preset long --out "$D/s11_oracle_long"; } &
wait
