#!/usr/bin/env bash
# Every pairing the fifth round of docs/experiments/long_horizon_dev.md quotes; its output is
# compare.txt. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/discount
H=docs/results/trials/headline
for s in single_box multi_object heldout_objects; do
    for p in "$D/default_h12d_$s $H/default_h12_$s" "$D/default_h12d_$s $H/default_surface_$s"; do
        set -- $p
        echo "== $1 vs $2"
        se3push compare "$1" "$2" | sed -n 2,4p
    done
done
echo "== pooled, discounted long vs the default"
se3push compare $D/default_h12d_single_box $H/default_surface_single_box \
    --pair $D/default_h12d_multi_object $H/default_surface_multi_object \
    --pair $D/default_h12d_heldout_objects $H/default_surface_heldout_objects | tail -1
echo "== pooled, discounted long vs long"
se3push compare $D/default_h12d_single_box $H/default_h12_single_box \
    --pair $D/default_h12d_multi_object $H/default_h12_multi_object \
    --pair $D/default_h12d_heldout_objects $H/default_h12_heldout_objects | tail -1
