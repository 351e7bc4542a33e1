#!/usr/bin/env bash
# Every pairing the fifth round of docs/experiments/long_horizon_dev.md quotes; its output is
# compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/discount
H=docs/results/trials/headline
for s in single_box multi_object heldout_objects; do
    printf '%s\n' "$D/default_h12d_$s $H/default_h12_$s" "$D/default_h12d_$s $H/default_surface_$s"
done | each 2,4p
pooled() {  # the discounted long plan against ../headline's $1_* folders, pooled
    local s
    for s in single_box multi_object heldout_objects; do
        echo "$D/default_h12d_$s $H/$1_$s"
    done | pool
}
echo "== pooled, discounted long vs the default"
pooled default_surface
echo "== pooled, discounted long vs long"
pooled default_h12
