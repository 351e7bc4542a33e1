#!/usr/bin/env bash
# Every pairing the ninth round of docs/experiments/long_horizon_dev.md quotes; its output is
# compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/pinned
H=docs/results/trials/headline
for s in single_box multi_object heldout_objects; do
    echo "$D/default_long_pinned_$s $H/default_h12_$s"
    echo "$D/default_long_pinned_$s $H/default_surface_$s"
    echo "$D/default_pinned_$s $H/default_surface_$s"
done | each
for p in long_pinned_heldout_objects pinned_heldout_objects long_heldout_objects; do
    echo "$D/s9_default_$p $D/s9_default_heldout_objects"
done | each
echo "$D/s9_default_long_pinned_heldout_objects $D/s9_default_long_heldout_objects" | each
echo "== pooled over trial set 2, long pinned vs long"
set2 "$D/default_long_pinned_" "$H/default_h12_" | pool
echo "== pooled over trial set 2, long pinned vs the default"
set2 "$D/default_long_pinned_" "$H/default_surface_" | pool
echo "== pooled over trial set 2, the default pinned vs the default"
set2 "$D/default_pinned_" "$H/default_surface_" | pool
echo "== pooled over trial set 2 and seed 9, long pinned vs long"
{ set2 "$D/default_long_pinned_" "$H/default_h12_"
  echo "$D/s9_default_long_pinned_heldout_objects $D/s9_default_long_heldout_objects"; } | pool
echo "== pooled over trial set 2 and seed 9, the default pinned vs the default"
{ set2 "$D/default_pinned_" "$H/default_surface_"
  echo "$D/s9_default_pinned_heldout_objects $D/s9_default_heldout_objects"; } | pool
echo "$D/s9_oracle_long_heldout_objects $D/s9_oracle_heldout_objects" | each
for m in default oracle; do
    echo "== pooled over the seven sets of 50 run with both plans, long vs the default, $m"
    both_plans "$m" | pool
done
