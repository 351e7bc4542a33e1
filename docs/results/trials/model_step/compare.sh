#!/usr/bin/env bash
# Every pairing docs/experiments/model_step.md quotes (`se3push compare`, trial by trial);
# its output is compare.txt. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/model_step
H=docs/results/trials/headline
P=docs/results/trials/pre_push_seed5
for s in single_box multi_object heldout_objects; do
    for p in "$D/m2_default_$s $H/default_surface_$s" "$D/m2_long_$s $H/default_h12_$s" \
             "$D/m2_long_$s $D/m2_default_$s" "$D/m2_default_$s $H/oracle_surface_$s" \
             "$D/m2_long_$s $H/oracle_h12_$s"; do
        set -- $p
        echo "== $1 vs $2"
        se3push compare "$1" "$2" | sed -n 2,4p
    done
done
for p in "$D/m2_default_s5_heldout_objects $P/default_surface_heldout_objects" \
         "$D/m2_long_s5_heldout_objects $P/default_long_heldout_objects" \
         "$D/m2_long_s5_heldout_objects $D/m2_default_s5_heldout_objects" \
         "$D/m2_default_s5_multi_object $P/default_surface_multi_object" \
         "$D/m2_long_s5_multi_object $D/m2_default_s5_multi_object"; do
    set -- $p
    echo "== $1 vs $2"
    se3push compare "$1" "$2" | sed -n 2,3p
done
echo "== pooled, m2 long vs m2 default (trial set 2 and seed 5)"
se3push compare $D/m2_long_single_box $D/m2_default_single_box \
    --pair $D/m2_long_multi_object $D/m2_default_multi_object \
    --pair $D/m2_long_heldout_objects $D/m2_default_heldout_objects \
    --pair $D/m2_long_s5_heldout_objects $D/m2_default_s5_heldout_objects \
    --pair $D/m2_long_s5_multi_object $D/m2_default_s5_multi_object | tail -1
echo "== pooled, m2 default vs shipped default (trial set 2 and seed 5)"
se3push compare $D/m2_default_single_box $H/default_surface_single_box \
    --pair $D/m2_default_multi_object $H/default_surface_multi_object \
    --pair $D/m2_default_heldout_objects $H/default_surface_heldout_objects \
    --pair $D/m2_default_s5_heldout_objects $P/default_surface_heldout_objects \
    --pair $D/m2_default_s5_multi_object $P/default_surface_multi_object | tail -1
echo "== pooled, m2 long vs shipped long (trial set 2 and seed 5's held-out)"
se3push compare $D/m2_long_single_box $H/default_h12_single_box \
    --pair $D/m2_long_multi_object $H/default_h12_multi_object \
    --pair $D/m2_long_heldout_objects $H/default_h12_heldout_objects \
    --pair $D/m2_long_s5_heldout_objects $P/default_long_heldout_objects | tail -1
