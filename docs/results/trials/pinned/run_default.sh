#!/usr/bin/env bash
# The default planner with the pusher's points pinned to its commanded path (--set
# rollout.exact_pusher=true: the code of commit baabfcd, removed after it), the shipped model
# on trial set 2 (--seed 0, 50 trials per scenario, run on to 1 cm and 5 deg) and on the fresh
# held-out set of run_seed9.sh, paired with ../headline/default_surface_* and
# s9_default_heldout_objects in compare.sh. One worker.
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pinned
run() { se3push trials --n 50 --workers 1 --tolerance precise --model default \
    --set rollout.exact_pusher=true "$@"; }
for s in heldout_objects multi_object single_box; do
    run --seed 0 --scenario "$s" --out "$D/default_pinned_$s"
done
run --seed 9 --scenario heldout_objects --out "$D/s9_default_pinned_heldout_objects"
