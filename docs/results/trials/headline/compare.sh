#!/usr/bin/env bash
# Every pairing of the headline table that the README and docs/planner.md quote, with
# `se3push compare` (paired trial by trial); its output is compare.txt. Run from the root.
set -euo pipefail
D=docs/results/trials/headline
for s in single_box multi_object heldout_objects; do
    for p in "default_long_$s default_$s" "oracle_long_$s oracle_$s" "default_$s oracle_$s" \
             "default_long_$s oracle_long_$s" "default_$s oracle_long_$s" \
             "default_surface_$s default_$s" "oracle_surface_$s oracle_$s" \
             "default_surface_$s oracle_surface_$s" "oracle_surface_$s oracle_long_$s" \
             "default_h12_$s default_surface_$s" "oracle_h12_$s oracle_surface_$s" \
             "default_h12_$s default_long_$s" "oracle_h12_$s oracle_long_$s" \
             "default_h12_$s oracle_h12_$s"; do
        set -- $p
        echo "== $1 vs $2"
        se3push compare "$D/$1" "$D/$2" | sed -n 2,5p
    done
done
