#!/usr/bin/env bash
# The long preset (1.2 s ahead, the shaping at every step) on the second fresh set's held-out
# objects (--seed 5, 50 trials), with the simulator and the shipped model, paired with the
# default's folders beside it (run.sh); about 20 minutes on two cores. Run from the root.
set -euo pipefail
D=docs/results/trials/pre_push_seed5
for m in default oracle; do
    se3push trials --scenario heldout_objects --n 50 --seed 5 --workers 2 --model $m \
        --preset long --out $D/${m}_long_heldout_objects
done
for m in default oracle; do
    se3push compare $D/${m}_long_heldout_objects $D/${m}_surface_heldout_objects | sed -n 2,3p
done
# pooled with trial set 2's three scenarios (the shipped model)
H=docs/results/trials/headline
se3push compare $H/default_h12_single_box $H/default_surface_single_box \
    --pair $H/default_h12_multi_object $H/default_surface_multi_object \
    --pair $H/default_h12_heldout_objects $H/default_surface_heldout_objects \
    --pair $D/default_long_heldout_objects $D/default_surface_heldout_objects | tail -1
