"""The simulator-as-model replan before it was batched: run in a checkout of commit cccf23a
(`git worktree add /tmp/old cccf23a && cd /tmp/old && PYTHONPATH=. python
PATH/TO/docs/results/bench_oracle_per_candidate.py`), on the states and plans of
`se3push bench horizon` (medians of 3 replans, one torch thread)."""

import dataclasses
import json

import torch

from planner import PlanSettings, PushCost, make_dynamics, make_planner, plan_state
from se3push.bench import _bench_state, median_seconds
from se3push.bench_horizon import LONG
from sim import PushWorld

torch.set_num_threads(1)
out = {}
sc, world, near, goal = _bench_state("cpu")
start = PushWorld(sc)
app = plan_state(start.reset(3), start)
for where, (w, st) in {"near": (world, near), "approach": (start, app)}.items():
    for name, h in (("today_3_steps", {}), ("long", LONG)):
        plan = PlanSettings()
        cfg = dataclasses.replace(plan.optimiser, **h)
        dyn = make_dynamics("oracle", sc, world=w)
        p = make_planner("cem", dyn, PushCost(sc, goal, plan.cost), sc, cfg)
        ms = 1e3 * median_seconds(lambda p=p, st=st: p.plan(st), repeats=3, warmup=1)
        out[f"{where}[simulator_{name}]"] = ms
print(json.dumps(out, indent=1))
