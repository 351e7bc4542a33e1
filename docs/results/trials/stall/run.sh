#!/usr/bin/env bash
# Today's planner with a plan that looks 1.2 s ahead through 4 cubic knots once the push stalls
# (--set optimiser.stall_horizon_s=1.2 --set optimiser.spline=cubic, the code of commit
# ac14caa, removed after it: docs/experiments/long_horizon_dev.md, seventh round), on trial
# set 2 (--seed 0, 50 trials per scenario, run on to 1 cm and 5 deg) with the shipped model
# and the simulator: paired with the default_surface_* and oracle_surface_* folders of
# ../headline (compare.sh). One queue, two workers.
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/stall
ST="--set optimiser.stall_horizon_s=1.2 --set optimiser.spline=cubic"
for m in default oracle; do
    for s in single_box multi_object heldout_objects; do
        se3push trials --n 50 --seed 0 --workers 2 --tolerance precise $ST --model $m \
            --scenario $s --out "$D/${m}_stall_$s"
    done
done
