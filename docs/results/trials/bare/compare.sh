#!/usr/bin/env bash
# Every pairing the thirteenth round of docs/experiments/long_horizon_dev.md quotes; its output
# is compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/bare
echo "== dev sets (--seed 1), the pose model: long without keep-out and fade against long"
set2 "$D/dev_pose_bare_" "$D/dev_pose_long_" | each
set2 "$D/dev_pose_bare_" "$D/dev_pose_long_" | pool
