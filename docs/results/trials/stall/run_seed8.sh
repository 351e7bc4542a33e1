#!/usr/bin/env bash
# A fresh set, --seed 8 (no run had drawn it), to confirm the plan that looks further ahead
# once the push stalls before it could become the default: held-out objects with the
# simulator and the shipped model, among others with the shipped model, each with and without
# it (the code of commit ac14caa; run on to 2 cm and 10 deg). One queue, two workers.
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/stall
ST="--set optimiser.stall_horizon_s=1.2 --set optimiser.spline=cubic"
run() { se3push trials --n 50 --seed 8 --workers 2 "$@"; }
for m in oracle default; do
    run --model $m --scenario heldout_objects --out "$D/s8_${m}_heldout_objects"
    run --model $m --scenario heldout_objects $ST --out "$D/s8_${m}_stall_heldout_objects"
done
run --model default --scenario multi_object --out "$D/s8_default_multi_object"
run --model default --scenario multi_object $ST --out "$D/s8_default_stall_multi_object"
# the long preset on the same held-out set, both models, one worker each, side by side (run
# after the code of ac14caa was removed)
for m in oracle default; do
    se3push trials --n 50 --seed 8 --workers 1 --preset long --model $m \
        --scenario heldout_objects --out "$D/s8_${m}_long_heldout_objects" &
done
wait
