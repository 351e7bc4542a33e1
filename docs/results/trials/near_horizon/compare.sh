#!/usr/bin/env bash
# Every pairing the sixth round of docs/experiments/long_horizon_dev.md quotes; its output is
# compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/near_horizon
H=docs/results/trials/headline
P=docs/results/trials/pre_push_seed5
SETS="single_box multi_object heldout_objects"
pairs() {  # trial set 2's pairs, A's folders $1_*, B's $H/$2_*; then the seed-5 pairs given
    local s
    for s in $SETS; do echo "$1_$s $H/$2_$s"; done
    shift 2
    if (($#)); then printf '%s\n' "$@"; fi
}
for s in $SETS; do
    for b in default_surface default_h12; do
        echo "== $D/default_nh5_$s vs $H/${b}_$s"
        se3push compare "$D/default_nh5_$s" "$H/${b}_$s" | sed -n 2,4p
    done
done
echo "== pooled, near-goal horizon vs the default"
pairs $D/default_nh5 default_surface | pool
echo "== pooled, near-goal horizon vs long"
pairs $D/default_nh5 default_h12 | pool
printf '%s\n' "$D/s5_default_nh5_heldout_objects $P/default_surface_heldout_objects" \
    "$D/s5_default_nh5_heldout_objects $P/default_long_heldout_objects" \
    "$D/s5_default_nh5_multi_object $P/default_surface_multi_object" \
    "$D/s5_default_long_multi_object $P/default_surface_multi_object" \
    "$D/s5_default_nh5_multi_object $D/s5_default_long_multi_object" \
    "$D/s5_oracle_long_multi_object $P/oracle_surface_multi_object" | each
echo "== pooled over both sets (250 trials), near-goal horizon vs the default"
pairs $D/default_nh5 default_surface "$D/s5_default_nh5_heldout_objects $P/default_surface_heldout_objects" \
    "$D/s5_default_nh5_multi_object $P/default_surface_multi_object" | pool
echo "== pooled over the same 250 trials, long vs the default"
pairs $H/default_h12 default_surface "$P/default_long_heldout_objects $P/default_surface_heldout_objects" \
    "$D/s5_default_long_multi_object $P/default_surface_multi_object" | pool
