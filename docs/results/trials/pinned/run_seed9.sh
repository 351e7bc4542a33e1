#!/usr/bin/env bash
# A fresh held-out set no run had drawn (--seed 9, 50 trials, run on to 1 cm and 5 deg), the
# shipped model with the long preset with and without the pinned pusher, and with the default:
# the confirmation of the ninth round of docs/experiments/long_horizon_dev.md (compare.sh).
# One worker. With SIM=1 the simulator's two runs alone.
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pinned
run() { se3push trials --n 50 --seed 9 --workers 1 --tolerance precise --model default \
    --scenario heldout_objects "$@"; }
if [[ ${SIM:-} != 1 ]]; then
    # rollout.exact_pusher: the code of commit baabfcd (removed after it)
    run --preset long --set rollout.exact_pusher=true \
        --out "$D/s9_default_long_pinned_heldout_objects"
    run --preset long --out "$D/s9_default_long_heldout_objects"
    run --out "$D/s9_default_heldout_objects"
fi
# the simulator on the same set, with the default and with long (one worker each, side by side)
sim() { se3push trials --n 50 --seed 9 --workers 1 --tolerance precise --model oracle \
    --scenario heldout_objects "$@"; }
if [[ ${SIM:-} == 1 ]]; then
    sim --out "$D/s9_oracle_heldout_objects" &
    sim --preset long --out "$D/s9_oracle_long_heldout_objects"
    wait
fi
