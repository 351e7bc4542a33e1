#!/usr/bin/env bash
# The long preset with a horizon that shortens near the goal: 0.45 s, a knot per step, once the
# object is within 5 cm of the goal's position (--set optimiser.near_horizon_s=0.45 --set
# optimiser.near_horizon_m=0.05, the code of commit 3e655bf: docs/experiments/long_horizon_dev.md,
# sixth round), on trial set 2 (--seed 0, 50 trials per scenario, run on to 1 cm and 5 deg),
# with the shipped model: paired with the default_surface_* and default_h12_* folders of
# ../headline (compare.sh). Two queues of one worker each (multi_object beside the other two).
# Then a second set, --seed 5 on the held-out objects and among others (run on to 2 cm and 10
# deg, as the folders of ../pre_push_seed5 it pairs with), one worker each, side by side.
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/near_horizon
run() { se3push trials --n 50 --seed 0 --workers 1 --tolerance precise --preset long \
            --set optimiser.near_horizon_s=0.45 --set optimiser.near_horizon_m=0.05 \
            --model default "$@"; }
run --scenario multi_object --out "$D/default_nh5_multi_object" &
for s in heldout_objects single_box; do
    run --scenario "$s" --out "$D/default_nh5_$s"
done
wait
s5() { se3push trials --n 50 --seed 5 --workers 1 --preset long \
           --set optimiser.near_horizon_s=0.45 --set optimiser.near_horizon_m=0.05 \
           --model default --scenario "$1" --out "$D/s5_default_nh5_$1"; }
s5 heldout_objects &
s5 multi_object
wait
# long alone among others on the same set (--preset long, no near-goal horizon), with the
# shipped model and with the simulator, run after the code of 3e655bf was removed
for m in default oracle; do
    se3push trials --n 50 --seed 5 --workers 2 --preset long --model $m --scenario multi_object \
        --out "$D/s5_${m}_long_multi_object"
done
