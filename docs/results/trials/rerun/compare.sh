#!/usr/bin/env bash
# The pairings README's known limits quotes: on one machine, the pose model (pose/default_*)
# against the shipped SE3-Net and the simulator made again here, and each rerun against the
# headline record it repeats. Its output is compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/rerun
P=docs/results/trials/pose
H=docs/results/trials/headline
echo "== one machine: the pose model against the shipped SE3-Net, the default planner"
set2 "$P/default_" "$D/default_" | each
set2 "$P/default_" "$D/default_" | pool
echo "== one machine: the pose model against the simulator, the default planner"
set2 "$P/default_" "$D/oracle_" | each
set2 "$P/default_" "$D/oracle_" | pool
echo "== one machine: the shipped SE3-Net against the simulator, the default planner"
set2 "$D/default_" "$D/oracle_" | each
echo "== the reruns against the headline records they repeat (two machines)"
set2 "$D/default_" "$H/default_surface_" | pool
set2 "$D/oracle_" "$H/oracle_surface_" | pool
