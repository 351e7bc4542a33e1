#!/usr/bin/env bash
# The planner 1.2 s ahead through 4 cubic knots with the shaping term charged at every step,
# and otherwise today's cost (keep-out, near-goal fade, pre-push point at the far side): the
# `long` preset since these records (--preset long gives the same settings as H12), with
# the shipped model and the simulator on trial set 2 (--seed 0), 50 trials per scenario, run on
# to 1 cm and 5 deg: paired with the default_surface_* and oracle_surface_* folders beside it
# (compare.sh). Two queues of one worker each, side by side: 48 minutes on two cores (the last
# set was finished by a second run with --workers 2 once the other queue had ended; the
# records are the same for any number of workers).
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/headline
H12="--set optimiser.horizon_s=1.2 --set optimiser.knots=4 --set optimiser.spline=cubic --set cost.shaping_at=every"
run() { se3push trials --n 50 --seed 0 --workers 1 --tolerance precise $H12 "$@"; }
(
    for s in heldout_objects multi_object single_box; do
        run --scenario "$s" --model default --out "$D/default_h12_$s"
    done
    run --scenario single_box --model oracle --out "$D/oracle_h12_single_box"
) &
for s in heldout_objects multi_object; do
    run --scenario "$s" --model oracle --out "$D/oracle_h12_$s"
done
wait
