#!/usr/bin/env bash
# The headline table (README): the shipped model and the simulator as the planner's model,
# under today's planner (the default) and the long one (--preset long), 50 trials per scenario
# (trial set 2: --seed 0), each run on to 1 cm and 5 deg so that success is measured at every
# tolerance. 73 minutes on two cores. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/headline
run() { se3push trials --n 50 --seed 0 --workers 2 --tolerance precise "$@"; }
for s in single_box multi_object heldout_objects; do
    run --scenario "$s" --model default --out "$D/default_$s"
done
for s in single_box multi_object heldout_objects; do
    run --scenario "$s" --model oracle --preset long --out "$D/oracle_long_$s"
done
for s in single_box multi_object heldout_objects; do
    run --scenario "$s" --model default --preset long --out "$D/default_long_$s"
done
for s in single_box multi_object heldout_objects; do
    run --scenario "$s" --model oracle --out "$D/oracle_$s"
done
