#!/usr/bin/env bash
# Every pairing docs/model.md's pose-model section and the README quote; its output is
# compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/pose
H=docs/results/trials/headline
echo "== dev sets (--seed 1): 20000 against 4000 training steps, the default and long"
for p in default long; do
    for s in single_box multi_object heldout_objects; do echo "$D/dev_20k_${p}_$s $D/dev_4k_${p}_$s"; done
done | pool
echo "== dev sets: the 20000-step model, long against the default"
set2 "$D/dev_20k_long_" "$D/dev_20k_default_" | each
set2 "$D/dev_20k_long_" "$D/dev_20k_default_" | pool
echo "== trial set 2: the pose model against the shipped SE3-Net, the default"
set2 "$D/default_" "$H/default_surface_" | each
set2 "$D/default_" "$H/default_surface_" | pool
echo "== trial set 2: the pose model against the simulator, the default"
set2 "$D/default_" "$H/oracle_surface_" | each
echo "== trial set 2: the pose model, long against the default"
set2 "$D/long_" "$D/default_" | each
set2 "$D/long_" "$D/default_" | pool
echo "== trial set 2: the pose model against the simulator, long"
set2 "$D/long_" "$H/oracle_h12_" | each
echo "== trial set 2: the pose model against the shipped SE3-Net, long"
set2 "$D/long_" "$H/default_h12_" | pool
[ -f "$D/s11_oracle_long/summary.json" ] || exit 0  # the fresh set still running
echo "== fresh held-out set (--seed 11)"
{ echo "$D/s11_pose_default $D/s11_se3net_default"
  echo "$D/s11_pose_default $D/s11_oracle_default"
  echo "$D/s11_pose_long $D/s11_pose_default"
  echo "$D/s11_se3net_long $D/s11_se3net_default"
  echo "$D/s11_oracle_long $D/s11_oracle_default"
  echo "$D/s11_pose_long $D/s11_oracle_long"; } | each
if [ -f "$D/s11_s128_default/summary.json" ]; then  # run_search.sh
    echo "== four times the search (samples 128), the default: dev sets, trial set 2, seed 11 held-out"
    set2 "$D/dev_s128_default_" "$D/dev_20k_default_" | each
    set2 "$D/dev_s128_default_" "$D/dev_20k_default_" | pool
    set2 "$D/s128_default_" "$D/default_" | pool
    echo "$D/s11_s128_default $D/s11_pose_default" | each
    echo "== four times the search, long against the default, dev sets"
    set2 "$D/dev_s128_long_" "$D/dev_s128_default_" | pool
fi
[ -f "$D/s11_oracle_default_multi_object/summary.json" ] || exit 0  # the trained objects still running
echo "== fresh set (--seed 11), the trained objects, the default planner"
for s in single_box multi_object; do
    echo "$D/s11_pose_default_$s $D/s11_se3net_default_$s"
    echo "$D/s11_pose_default_$s $D/s11_oracle_default_$s"
done | each
echo "== fresh set (--seed 11), all three scenarios pooled: the pose model against the SE3-Net, the default"
{ echo "$D/s11_pose_default $D/s11_se3net_default"
  for s in single_box multi_object; do echo "$D/s11_pose_default_$s $D/s11_se3net_default_$s"; done; } | pool
echo "== fresh set (--seed 11), all three scenarios pooled: the pose model against the simulator, the default"
{ echo "$D/s11_pose_default $D/s11_oracle_default"
  for s in single_box multi_object; do echo "$D/s11_pose_default_$s $D/s11_oracle_default_$s"; done; } | pool
[ -f "$D/s11_oracle_long_multi_object/summary.json" ] || exit 0  # run_seed11_long.sh still running
s11() {  # the seed-11 folder of model $1, plan $2, scenario $3 (its held-out folders are unsuffixed)
    if [ "$3" = heldout_objects ]; then echo "$D/s11_$1_$2"; else echo "$D/s11_$1_$2_$3"; fi
}
s11_all() {  # "A B" for the three scenarios: model $1 plan $2 against model $3 plan $4
    for s in single_box multi_object heldout_objects; do echo "$(s11 "$1" "$2" $s) $(s11 "$3" "$4" $s)"; done
}
echo "== fresh set (--seed 11), long against the default: the pose model"
s11_all pose long pose default | each
s11_all pose long pose default | pool
echo "== fresh set (--seed 11), long against the default: the simulator"
s11_all oracle long oracle default | each
s11_all oracle long oracle default | pool
echo "== fresh set (--seed 11), the pose model against the simulator, both long"
s11_all pose long oracle long | each
s11_all pose long oracle long | pool
