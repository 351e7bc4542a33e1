#!/usr/bin/env bash
# Every pairing the seventh round of docs/experiments/long_horizon_dev.md quotes; its output is
# compare.txt. Run from the repository's root.
set -euo pipefail
. docs/results/trials/compare_pairs.sh
D=docs/results/trials/stall
H=docs/results/trials/headline
for m in default oracle; do
    for s in single_box multi_object heldout_objects; do
        echo "$D/${m}_stall_$s $H/${m}_surface_$s"
    done
done | each
for p in oracle_heldout_objects default_heldout_objects default_multi_object; do
    echo "$D/s8_${p/_/_stall_} $D/s8_$p"
done | each
