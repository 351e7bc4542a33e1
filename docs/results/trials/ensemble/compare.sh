#!/usr/bin/env bash
# Every pairing the eleventh round of docs/experiments/long_horizon_dev.md quotes; its output
# is compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/ensemble
L=docs/results/trials/dev_long
H=docs/results/trials/headline
echo "== dev sets: the ensemble, long, against the shipped model long and default"
for b in "$L/default_longh_every" "$L/default_surface"; do echo "$D/dev_ens3_long $b"; done | each
for b in "$L/default_long_multi_object" "$L/default_multi_object"; do
    echo "$D/dev_ens3_long_multi_object $b"
done | each
dev() {  # a checkpoint's two dev sets, long against the default: $1 the long prefix, $2 the default's
    echo "$1 $2"
    echo "$1_multi_object $2_multi_object"
}
for s in 1 2; do
    echo "== dev sets, seed-$s generalist, long vs the default"
    dev "$D/dev_seed${s}_long" "$D/dev_seed${s}_default" | each
    dev "$D/dev_seed${s}_long" "$D/dev_seed${s}_default" | pool
done
echo "== dev sets, the shipped model, long vs the default"
{ echo "$L/default_longh_every $L/default_surface"
  echo "$L/default_long_multi_object $L/default_multi_object"; } | pool
echo "== dev sets, the three checkpoints pooled, long vs the default"
{ dev "$D/dev_seed1_long" "$D/dev_seed1_default"; dev "$D/dev_seed2_long" "$D/dev_seed2_default"
  echo "$L/default_longh_every $L/default_surface"
  echo "$L/default_long_multi_object $L/default_multi_object"; } | pool
[ -f "$D/seed2_long_single_box/summary.json" ] || exit 0  # trial set 2 still running
for s in 1 2; do
    echo "== trial set 2, seed-$s generalist, long vs the default"
    set2 "$D/seed${s}_long_" "$D/seed${s}_default_" | each
    set2 "$D/seed${s}_long_" "$D/seed${s}_default_" | pool
    echo "== trial set 2, seed-$s generalist against the shipped model, the default"
    set2 "$D/seed${s}_default_" "$H/default_surface_" | pool
    echo "== trial set 2, seed-$s generalist against the shipped model, long"
    set2 "$D/seed${s}_long_" "$H/default_h12_" | pool
done
echo "== trial set 2, the shipped model, long vs the default"
set2 "$H/default_h12_" "$H/default_surface_" | pool
echo "== trial set 2, the three checkpoints pooled, long vs the default"
{ set2 "$D/seed1_long_" "$D/seed1_default_"; set2 "$D/seed2_long_" "$D/seed2_default_"
  set2 "$H/default_h12_" "$H/default_surface_"; } | pool
echo "== trial set 2, the two other seeds pooled, long vs the default"
{ set2 "$D/seed1_long_" "$D/seed1_default_"; set2 "$D/seed2_long_" "$D/seed2_default_"; } | pool
[ -f "$D/s10_default_long_heldout_objects/summary.json" ] || exit 0  # seed 10 still running
s10() {  # seed 10's pairs, long against the default: the two new seeds and the shipped model
    for m in seed1_ seed2_; do
        echo "$D/s10_${m}long_heldout_objects $D/s10_${m}default_heldout_objects"
    done
    echo "$D/s10_default_long_heldout_objects $D/s10_default_heldout_objects"
}
echo "== fresh held-out set (seed 10), long vs the default, each checkpoint"
s10 | each
echo "== fresh held-out set (seed 10), the three checkpoints pooled, long vs the default"
s10 | pool
echo "== trial set 2 and seed 10, the three checkpoints pooled, long vs the default"
{ set2 "$D/seed1_long_" "$D/seed1_default_"; set2 "$D/seed2_long_" "$D/seed2_default_"
  set2 "$H/default_h12_" "$H/default_surface_"; s10; } | pool
[ -f "$D/s10_oracle_long_heldout_objects/summary.json" ] || exit 0  # the simulator still running
echo "$D/s10_oracle_long_heldout_objects $D/s10_oracle_heldout_objects" | each
for m in default oracle; do
    echo "== pooled over the eight sets of 50 run with both plans (seed 10 added), long vs the default, $m"
    { both_plans "$m"; echo "$D/s10_${m}_long_heldout_objects $D/s10_${m}_heldout_objects"; } | pool
done
