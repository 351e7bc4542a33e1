#!/usr/bin/env bash
# The long preset with the pusher's points pinned to its commanded path in every fed-back cloud
# (--set rollout.exact_pusher=true: the code of commit baabfcd, removed after it), the shipped
# model on trial set 2 (--seed 0, 50 trials per scenario, run on to 1 cm and 5 deg), paired
# with ../headline's default_surface_* (the default) and default_h12_* (long) in compare.sh.
# The simulator ignores the setting: its long rows are ../headline/oracle_h12_*. One worker a
# scenario, the scenarios given as arguments (run side by side in two queues).
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pinned
for s in "$@"; do
    se3push trials --n 50 --seed 0 --workers 1 --tolerance precise --preset long \
        --set rollout.exact_pusher=true --model default --scenario "$s" \
        --out "$D/default_long_pinned_$s"
done
