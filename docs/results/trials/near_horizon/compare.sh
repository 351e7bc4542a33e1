#!/usr/bin/env bash
# Every pairing the sixth round of docs/experiments/long_horizon_dev.md quotes; its output is
# compare.txt. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/near_horizon
H=docs/results/trials/headline
P=docs/results/trials/pre_push_seed5
pooled() {
    se3push compare $D/default_nh5_single_box $H/${1}_single_box \
        --pair $D/default_nh5_multi_object $H/${1}_multi_object \
        --pair $D/default_nh5_heldout_objects $H/${1}_heldout_objects | tail -1
}
for s in single_box multi_object heldout_objects; do
    for b in default_surface default_h12; do
        echo "== $D/default_nh5_$s vs $H/${b}_$s"
        se3push compare "$D/default_nh5_$s" "$H/${b}_$s" | sed -n 2,4p
    done
done
echo "== pooled, near-goal horizon vs the default"
pooled default_surface
echo "== pooled, near-goal horizon vs long"
pooled default_h12
for p in "$D/s5_default_nh5_heldout_objects $P/default_surface_heldout_objects" \
         "$D/s5_default_nh5_heldout_objects $P/default_long_heldout_objects" \
         "$D/s5_default_nh5_multi_object $P/default_surface_multi_object" \
         "$D/s5_default_long_multi_object $P/default_surface_multi_object" \
         "$D/s5_default_nh5_multi_object $D/s5_default_long_multi_object"; do
    set -- $p
    echo "== $1 vs $2"
    se3push compare "$1" "$2" | sed -n 2,2p
done
echo "== pooled over both sets (250 trials), near-goal horizon vs the default"
se3push compare $D/default_nh5_single_box $H/default_surface_single_box \
    --pair $D/default_nh5_multi_object $H/default_surface_multi_object \
    --pair $D/default_nh5_heldout_objects $H/default_surface_heldout_objects \
    --pair $D/s5_default_nh5_heldout_objects $P/default_surface_heldout_objects \
    --pair $D/s5_default_nh5_multi_object $P/default_surface_multi_object | tail -1
echo "== pooled over the same 250 trials, long vs the default"
se3push compare $H/default_h12_single_box $H/default_surface_single_box \
    --pair $H/default_h12_multi_object $H/default_surface_multi_object \
    --pair $H/default_h12_heldout_objects $H/default_surface_heldout_objects \
    --pair $P/default_long_heldout_objects $P/default_surface_heldout_objects \
    --pair $D/s5_default_long_multi_object $P/default_surface_multi_object | tail -1
