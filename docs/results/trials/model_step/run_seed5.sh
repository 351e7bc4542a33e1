#!/usr/bin/env bash
# Needs the code of commit c851699 (docs/experiments/model_step.md), which rolls such a model.
# The model of two control steps a pass (runs/gen_s2_m2) on the second fresh set (--seed 5,
# 50 trials, the flags of ../pre_push_seed5/run.sh), default planner and long preset, held-out
# objects and among others: paired with the shipped model's folders in ../pre_push_seed5.
# One worker, beside run.sh's last queue. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/model_step
M=${M:-runs/gen_s2_m2/best.pt}
for s in heldout_objects multi_object; do
    se3push trials --scenario $s --n 50 --seed 5 --workers 1 --model "$M" --out $D/m2_default_s5_$s
    se3push trials --scenario $s --n 50 --seed 5 --workers 1 --model "$M" --preset long \
        --out $D/m2_long_s5_$s
done
