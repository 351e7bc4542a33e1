#!/usr/bin/env bash
# The simulator as model on the fresh held-out set (--seed 10, 50 trials, run on to 1 cm and
# 5 deg), the default and the long preset side by side, one worker each. Run from the
# repository's root.
set -euo pipefail
D=docs/results/trials/ensemble
export OMP_NUM_THREADS=1
run() { se3push trials --scenario heldout_objects --n 50 --seed 10 --workers 1 --tolerance precise --model oracle "$@"; }
run --out "$D/s10_oracle_heldout_objects" &
run --preset long --out "$D/s10_oracle_long_heldout_objects" &
wait
