#!/usr/bin/env bash
# A second fresh set for the pre-push point (docs/planner.md): held-out objects, --seed 5,
# 50 trials, today's default (surface) against --preset circle, with the simulator and the
# shipped model; about 16 minutes on two cores. Then the pooled comparison over this set and
# trial set 2 (docs/results/trials/headline). Run from the repository's root.
set -euo pipefail
D=docs/results/trials/pre_push_seed5
H=docs/results/trials/headline
run() { se3push trials --scenario heldout_objects --n 50 --seed 5 --workers 2 "$@"; }
run --model oracle --out $D/oracle_surface
run --model oracle --preset circle --out $D/oracle_circle
run --model default --out $D/default_surface
run --model default --preset circle --out $D/default_circle
for m in default oracle; do
    se3push compare $H/${m}_surface_single_box $H/${m}_single_box \
        --pair $H/${m}_surface_multi_object $H/${m}_multi_object \
        --pair $H/${m}_surface_heldout_objects $H/${m}_heldout_objects \
        --pair $D/${m}_surface $D/${m}_circle | tail -2
done
