"""The ninth round of long_horizon_dev.md: where the shipped model's fed-back clouds show the
pusher, and what pinning it to its commands does to the 8-step pose error.

Runs at commit baabfcd, which has ``rollout.exact_pusher`` (removed after it), from a work tree
of that commit so that its packages are the ones imported:

    git worktree add ../at_baabfcd baabfcd && cd ../at_baabfcd
    OMP_NUM_THREADS=1 PYTHONPATH=. python ../main/docs/experiments/pusher_lag.py

Prints, for 16 random constant commands from each of the first 6 held-out starts, how far the
pusher's points in the fed-back cloud are from where the commands put it after each of 8 steps
(the network's own prediction, rendered again); then the shipped model's pose error after 8
fed-back steps on 200 test windows of data/household and data/single_box (the README's data),
as ``se3push study`` measures it, with the pusher's points as predicted and as commanded.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

import evaluation.study as study
from planner import make_dynamics, plan_state
from planner.dynamics import to_world
from scenarios import load_scenario
from se3net.data import subsample
from sim import PushWorld
from sim.world import PART_PUSHER


def lag(episodes: int = 6, candidates: int = 16, steps: int = 8) -> None:
    scenario = load_scenario("heldout_objects")
    world = PushWorld(scenario)
    dyn = make_dynamics("se3net", scenario, feedback="rendered", contact_margin_m=0.01)
    rng = np.random.default_rng(0)
    v = scenario.action.max_speed_m_s
    err = np.zeros((episodes, steps))
    cmd = np.zeros((episodes, steps))
    for ep in range(episodes):
        obs = world.reset(ep)
        state = plan_state(obs, world)
        seen = subsample(torch.from_numpy(obs.part == PART_PUSHER) & state.valid, dyn.stride)
        sel = seen.flatten().nonzero()[:, 0]
        U = torch.from_numpy(rng.uniform(-v, v, (candidates, 1, 2))).float()
        U = U.expand(candidates, steps, 2).contiguous()
        with torch.inference_mode():
            rolled = dyn._rollout(state, U, clouds=True)
        observed = subsample(state.points, dyn.stride).flatten(1)[:, sel].T
        start = to_world(state.T_world_cam, observed)[:, :2].mean(0)
        for h in range(steps):
            cloud = rolled.clouds[:, h].flatten(2)[:, :, sel].transpose(1, 2)
            shown = to_world(state.T_world_cam, cloud)[..., :2].mean(1) - start
            commanded = rolled.pusher_xy[:, h] - state.pusher_xy
            err[ep, h] = (shown - commanded).norm(dim=-1).mean()
            cmd[ep, h] = commanded.norm(dim=-1).mean()
    for h in range(steps):
        print(
            f"after step {h + 1}: the pusher shown {1e3 * err[:, h].mean():.1f} mm from where "
            f"its commands put it ({1e3 * cmd[:, h].mean():.1f} mm from its start)"
        )


def horizon_error(steps: int = 8) -> None:
    windows = study._window_states

    def with_pusher(ds, pick, start, object_index):
        """The study's window states with the pusher's pixels (PlanState.pusher_mask)."""
        for s in range(0, len(pick), 64):
            b = ds.batch(pick[s : s + 64])
            part = windows(ds, pick[s : s + 64], start[s : s + 64], object_index)
            for j, (state, actions, obj) in enumerate(part):
                pusher = b["part"][j] == PART_PUSHER
                yield dataclasses.replace(state, pusher_mask=pusher), actions, obj

    study._window_states = with_pusher
    for exact in (False, True):

        def dynamics(model, scenario, feedback, margin, exact=exact):
            return make_dynamics("se3net", scenario, model=model, feedback=feedback,
                                 contact_margin_m=margin, exact_pusher=exact)  # fmt: skip

        study.study_dynamics = dynamics
        for data in ("data/household", "data/single_box"):
            r = study.horizon_pose_error("default", data, steps, max_windows=200)
            print(
                f"{data}, pusher {'commanded' if exact else 'predicted'}: "
                f"{r['horizon_pos_err_cm']:.2f} cm, {r['horizon_yaw_err_deg']:.1f} deg "
                f"after {steps} steps ({r['windows']} windows)"
            )


if __name__ == "__main__":
    torch.set_num_threads(1)
    lag()
    horizon_error()
