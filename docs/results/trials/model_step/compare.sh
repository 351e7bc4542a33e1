#!/usr/bin/env bash
# Every pairing docs/experiments/model_step.md quotes (`se3push compare`, trial by trial);
# its output is compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/model_step
H=docs/results/trials/headline
P=docs/results/trials/pre_push_seed5
for s in single_box multi_object heldout_objects; do
    printf '%s\n' "$D/m2_default_$s $H/default_surface_$s" "$D/m2_long_$s $H/default_h12_$s" \
        "$D/m2_long_$s $D/m2_default_$s" "$D/m2_default_$s $H/oracle_surface_$s" \
        "$D/m2_long_$s $H/oracle_h12_$s"
done | each 2,4p
printf '%s\n' "$D/m2_default_s5_heldout_objects $P/default_surface_heldout_objects" \
    "$D/m2_long_s5_heldout_objects $P/default_long_heldout_objects" \
    "$D/m2_long_s5_heldout_objects $D/m2_default_s5_heldout_objects" \
    "$D/m2_default_s5_multi_object $P/default_surface_multi_object" \
    "$D/m2_long_s5_multi_object $D/m2_default_s5_multi_object" | each 2,3p
pairs() {  # A's folders $1_*, B's $2_* over trial set 2 and seed 5 ($3: seed 5's B prefix,
    # $4: also seed 5's among others)
    local s
    for s in single_box multi_object heldout_objects; do echo "$D/$1_$s $2_$s"; done
    echo "$D/$1_s5_heldout_objects $3_heldout_objects"
    if [ "$4" = yes ]; then echo "$D/$1_s5_multi_object $3_multi_object"; fi
}
echo "== pooled, m2 long vs m2 default (trial set 2 and seed 5)"
pairs m2_long $D/m2_default $D/m2_default_s5 yes | pool
echo "== pooled, m2 default vs shipped default (trial set 2 and seed 5)"
pairs m2_default $H/default_surface $P/default_surface yes | pool
echo "== pooled, m2 long vs shipped long (trial set 2 and seed 5's held-out)"
pairs m2_long $H/default_h12 $P/default_long no | pool
