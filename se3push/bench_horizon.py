"""``se3push bench horizon``: what a long horizon costs a replan with the learned model, and what
each lever saves: knots (fewer values to sample, not fewer network passes) and skipping the
network for candidates that never come within reach of an object; and what it costs with the
simulator as the model (every candidate in one batched MuJoCo rollout, ``sim.batch``) and with
a pose-space model (``se3net.pose_model``: poses rolled, no clouds).

Every figure is a median over repeats of one CEM replan with the shipped SE3-Net (or the
shipped pose model, the ``pose_`` figures) rolled as the planner rolls it (rendered feedback,
the contact gate), on single_box in two states: ``near``
(the pusher a few centimetres from the box, where most candidates touch it) and ``approach``
(the world's start, the pusher well away from the box).
"""

from __future__ import annotations

import numpy as np

POSE = "pose"
"""the shipped pose-space model (``se3net.pose_model``), timed beside the SE3-Net"""
LONG = "long"
"""the preset whose plan is timed as the long one: 8 steps of 0.15 s (1.2 s) through 4 cubic
knots, the shaping term charged at every step"""


def _states(device: str) -> tuple:
    from planner import plan_state
    from se3push.bench import _bench_state
    from sim import PushWorld

    scenario, world, near, goal = _bench_state(device)
    start = PushWorld(scenario)
    states = {"near": near, "approach": plan_state(start.reset(3), start)}
    return scenario, goal, states, {"near": world, "approach": start}


def _replan_ms(preset: str, skip: bool, *, state, scenario, goal, repeats: int, model,
               device: str, world=None) -> float:  # fmt: skip
    """One CEM replan's median (ms) with the settings of ``preset``: ``model`` (None: the
    shipped SE3-Net) as the planner rolls it, or, given ``world``, the simulator."""
    from planner import PushCost, make_dynamics, make_planner
    from planner.presets import preset_settings
    from se3push.bench import median_seconds

    plan = preset_settings(preset)
    if world is not None:
        dyn = make_dynamics("oracle", scenario, world=world)
        repeats = max(3, repeats // 4)
    else:
        dyn = make_dynamics("se3net", scenario, model=model, device=device,
                            feedback=plan.rollout.feedback,
                            contact_margin_m=plan.rollout.contact_margin_m)  # fmt: skip
        if hasattr(dyn, "skip_out_of_reach"):  # a pose model has no network passes to skip
            dyn.skip_out_of_reach = skip
    planner = make_planner("cem", dyn, PushCost(scenario, goal, plan.cost), scenario,
                           plan.optimiser)  # fmt: skip
    return 1e3 * median_seconds(lambda: planner.plan(state), repeats=repeats, warmup=2)


def _side_by_side(repeats: int, model: str | None) -> float:
    """One of two processes timing the long plan with the skip at once (1 torch thread), with
    ``model`` (None: the shipped SE3-Net)."""
    import torch

    torch.set_num_threads(1)
    scenario, goal, states, _ = _states("cpu")
    return _replan_ms(LONG, True, state=states["near"], scenario=scenario, goal=goal,
                      repeats=repeats, model=model, device="cpu")  # fmt: skip


def bench_horizon(
    *, repeats: int, model: str | None = None, device: str = "cpu", **_: object
) -> dict:
    """Median replan (ms) of today's 3-step plan and of the 1.2 s plan (``LONG``) with and
    without the network skip, near the box and on the approach; the long plan with the skip in
    two processes side by side; both plans with the simulator and with the shipped pose model
    as the model."""
    from se3net.device import check_device
    from sim.jobs import Backend, run_jobs

    check_device(device)
    scenario, goal, states, worlds = _states(device)
    out: dict[str, dict[str, float]] = {}
    for where, state in states.items():
        timed = {"state": state, "scenario": scenario, "goal": goal, "repeats": repeats,
                 "model": model, "device": device}  # fmt: skip
        out[where] = {
            "today_3_steps": _replan_ms("default", True, **timed),
            "long_full_network": _replan_ms(LONG, False, **timed),
            "long_with_skip": _replan_ms(LONG, True, **timed),
            "simulator_today_3_steps": _replan_ms("default", True, **timed, world=worlds[where]),
            "simulator_long": _replan_ms(LONG, True, **timed, world=worlds[where]),
            "pose_today_3_steps": _replan_ms("default", True, **{**timed, "model": POSE}),
            "pose_long": _replan_ms(LONG, True, **{**timed, "model": POSE}),
        }
    pair = list(run_jobs(_side_by_side, [(repeats, model)] * 2, Backend(workers=2)))
    out["near"]["long_with_skip_two_processes"] = float(np.median(pair))
    pair = list(run_jobs(_side_by_side, [(repeats, POSE)] * 2, Backend(workers=2)))
    out["near"]["pose_long_two_processes"] = float(np.median(pair))
    return out
