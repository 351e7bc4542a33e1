#!/usr/bin/env bash
# The two other-seed generalists (runs/gen_s2_seed1, runs/gen_s2_seed2: the shipped model's
# command with --seed 1 and --seed 2, run_dev.sh) on trial set 2 (--seed 0, 50 trials per
# scenario, run on to 1 cm and 5 deg), with the default and the long preset: paired with the
# shipped model's headline/default_surface_* and headline/default_h12_* folders (compare.sh).
# Two queues of one worker each, one per model, side by side. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/ensemble
export OMP_NUM_THREADS=1
run() { se3push trials --n 50 --seed 0 --workers 1 --tolerance precise "$@"; }
queue() {
    s=$1
    M=runs/gen_s2_seed$s/best.pt
    for sc in heldout_objects multi_object single_box; do
        run --scenario "$sc" --model "$M" --out "$D/seed${s}_default_$sc"
        run --scenario "$sc" --model "$M" --preset long --out "$D/seed${s}_long_$sc"
    done
}
queue 1 &
queue 2 &
wait
