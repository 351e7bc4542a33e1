#!/usr/bin/env bash
# A second fresh set for the pre-push point (docs/planner.md): --seed 5, 50 trials per
# scenario, today's default (surface) against --preset circle, with the simulator and the
# shipped model, on the held-out objects and among others; about 32 minutes on two cores.
# Then the comparison pooled with trial set 2 (docs/results/trials/headline). Run from the
# repository's root.
set -euo pipefail
D=docs/results/trials/pre_push_seed5
H=docs/results/trials/headline
for s in heldout_objects multi_object; do
    run() { se3push trials --scenario $s --n 50 --seed 5 --workers 2 "$@"; }
    run --model oracle --out $D/oracle_surface_$s
    run --model oracle --preset circle --out $D/oracle_circle_$s
    run --model default --out $D/default_surface_$s
    run --model default --preset circle --out $D/default_circle_$s
done
for m in default oracle; do
    se3push compare $H/${m}_surface_single_box $H/${m}_single_box \
        --pair $H/${m}_surface_multi_object $H/${m}_multi_object \
        --pair $H/${m}_surface_heldout_objects $H/${m}_heldout_objects \
        --pair $D/${m}_surface_heldout_objects $D/${m}_circle_heldout_objects \
        --pair $D/${m}_surface_multi_object $D/${m}_circle_multi_object | tail -2
done
