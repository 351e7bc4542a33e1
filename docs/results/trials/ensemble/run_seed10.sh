#!/usr/bin/env bash
# A fresh held-out set no run had drawn (--seed 10, 50 trials, run on to 1 cm and 5 deg): the
# two other-seed generalists and the shipped model, each with the default and the long preset,
# two queues of one worker each. Run from the repository's root, after run_dev.sh's training commands.
set -euo pipefail
D=docs/results/trials/ensemble
export OMP_NUM_THREADS=1
run() { se3push trials --scenario heldout_objects --n 50 --seed 10 --workers 1 --tolerance precise "$@"; }
seed() {
    M=runs/gen_s2_seed$1/best.pt
    run --model "$M" --out "$D/s10_seed$1_default_heldout_objects"
    run --model "$M" --preset long --out "$D/s10_seed$1_long_heldout_objects"
}
(seed 1; run --model default --out "$D/s10_default_heldout_objects") &
(seed 2; run --model default --preset long --out "$D/s10_default_long_heldout_objects") &
wait
