#!/usr/bin/env bash
# Needs the code of commit c851699 (docs/experiments/model_step.md), which rolls such a model.
# The model of two control steps a pass (runs/gen_s2_m2, the README's recipe with
# --model-step 2) on trial set 2 (--seed 0, 50 trials per scenario, run on to 1 cm and 5 deg),
# with the default planner and the long preset: paired with the shipped model's and the
# simulator's folders in ../headline (compare.sh). Two queues of one worker each, side by side.
# Run from the repository's root.
set -euo pipefail
D=docs/results/trials/model_step
M=${M:-runs/gen_s2_m2/best.pt}
run() { se3push trials --n 50 --seed 0 --workers 1 --tolerance precise --model "$M" "$@"; }
(
    for s in heldout_objects multi_object single_box; do
        run --scenario "$s" --out "$D/m2_default_$s"
    done
) &
for s in heldout_objects multi_object single_box; do
    run --scenario "$s" --preset long --out "$D/m2_long_$s"
done
wait
