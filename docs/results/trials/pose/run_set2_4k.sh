#!/usr/bin/env bash
# Trial set 2 with the 4000-step pose model (runs/pose_4k, run_dev.sh's command; not committed),
# the default planner: run once before the dev sets chose 20000 steps (docs/model.md says so).
# Two workers. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pose
export OMP_NUM_THREADS=1
for sc in single_box multi_object heldout_objects; do
    se3push trials --scenario "$sc" --n 50 --seed 0 --workers 2 --tolerance precise \
        --model runs/pose_4k/best.pt --out "$D/set2_4k_default_$sc"
done
