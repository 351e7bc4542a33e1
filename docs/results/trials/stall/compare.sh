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
for m in oracle default; do
    echo "$D/s8_${m}_long_heldout_objects $D/s8_${m}_heldout_objects"
done | each
P=docs/results/trials/pre_push_seed5
N=docs/results/trials/near_horizon
for m in default oracle; do
    echo "== pooled over trial set 2, seed 5 and seed 8 (300 trials), long vs the default, $m"
    {
        for s in single_box multi_object heldout_objects; do
            echo "$H/${m}_h12_$s $H/${m}_surface_$s"
        done
        echo "$P/${m}_long_heldout_objects $P/${m}_surface_heldout_objects"
        echo "$N/s5_${m}_long_multi_object $P/${m}_surface_multi_object"
        echo "$D/s8_${m}_long_heldout_objects $D/s8_${m}_heldout_objects"
    } | pool
done
