#!/usr/bin/env bash
# Every pairing docs/planner.md quotes for SQP's sampled starts; its output is compare.txt.
# Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/sqp_starts
pairs() {
    for f in pose_single_box pose_heldout_objects default_single_box default_heldout_objects; do
        echo "$D/$f $D/before_$f"
    done
}
echo "== SQP from sampled starts against SQP from the warm start (before_), dev sets"
pairs | each
echo "== the pose model pooled"
pairs | grep "/pose_" | pool
echo "== the shipped SE3-Net pooled"
pairs | grep "/default_" | pool
echo "== all four pooled"
pairs | pool
