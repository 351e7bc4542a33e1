#!/usr/bin/env bash
# SQP from the best of sampled starts (grad's, `optimiser.grad_init_samples`) against SQP from
# the warm start alone, on the dev sets (--seed 1), with the pose model and the shipped
# SE3-Net. The folders without a prefix ran at commit 468cf1b, which starts SQP from the
# samples (reverted in the commit after it); the before_ ones ran the same commands at
# 6c4d2e4, the commit before it, as SQP is today (`git worktree add /tmp/before 6c4d2e4`, then
# these commands from there with PYTHONPATH=/tmp/before and --out pointing here). Two queues
# of one worker each, side by side. Run from the repository's root.
set -euo pipefail
D=docs/results/trials/sqp_starts
export OMP_NUM_THREADS=1
run() { se3push trials --seed 1 --workers 1 --planner sqp "$@"; }
{ run --scenario single_box --n 30 --model pose --out $D/pose_single_box
  run --scenario heldout_objects --n 20 --model default --out $D/default_heldout_objects; } &
{ run --scenario single_box --n 30 --model default --out $D/default_single_box
  run --scenario heldout_objects --n 30 --model pose --out $D/pose_heldout_objects; } &
wait
