"""``se3push bench``: medians of repeated timings of the hot paths, printed and as JSON."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np


def median_seconds(fn: Callable[[], object], *, repeats: int, warmup: int = 2) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def bench_world(*, repeats: int) -> dict[str, float]:
    """Camera frames/s at 64x64 and 240x320, and control steps/s (0.15 s of simulated time
    each, with the controller and a 64x64 render) on ``single_box``."""
    from scenarios import load_scenario
    from sim import PushWorld

    scenario = load_scenario("single_box")
    out = {}
    for w, h in ((64, 64), (320, 240)):
        world = PushWorld(scenario, width=w, height=h)
        world.reset(0)
        out[f"camera_fps_{h}x{w}"] = 1.0 / median_seconds(
            lambda world=world: world.camera.render(world.model, world.data), repeats=repeats * 5
        )
    world = PushWorld(scenario)
    world.reset(0)
    rng = np.random.default_rng(0)

    def control_step() -> None:  # one step renders once: its observation
        if world.ended:
            world.reset(int(rng.integers(1 << 30)))
        world.step(rng.uniform(-0.1, 0.1, size=2))

    out["control_steps_per_s"] = 1.0 / median_seconds(control_step, repeats=repeats * 5)
    return out


def bench_data(*, repeats: int) -> dict[str, float]:
    """Examples/s of ``se3push data`` with 1 and 2 workers (24 episodes of 20 steps on
    ``single_box`` at 64x64, process start-up included), and stored bytes per example."""
    import tempfile

    from sim.dataset import DataConfig, generate

    cfg = DataConfig("single_box", episodes=24, episodes_per_shard=6)
    out: dict[str, float] = {}
    runs = max(1, min(repeats, 3))
    for workers in (1, 2):
        times, sizes = [], []
        for _ in range(runs):
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                manifest = generate(cfg, tmp, workers=workers, progress=False)
                times.append(time.perf_counter() - t0)
                sizes.append(sum(p.stat().st_size for p in Path(tmp).glob("shard_*.npz")))
        examples = manifest["stats"]["examples"]
        key = "1_worker" if workers == 1 else f"{workers}_workers"
        out[f"examples_per_s_{key}"] = examples / float(np.median(times))
    out["bytes_per_example"] = float(np.median(sizes)) / examples
    return out


def bench_model(*, repeats: int) -> dict[str, float]:
    """The SE3-Net (se3net variant, 64x64, k = 4) on CPU: Adam step time at batch 32 and
    inference samples/s (inference mode) at batch 1, 64 and 256."""
    import torch

    from se3net.metrics import point_loss
    from se3net.model import ModelConfig, build_model

    torch.manual_seed(0)
    model = build_model(ModelConfig())
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)

    def batch(n: int) -> tuple[torch.Tensor, ...]:
        pts = torch.randn(n, 3, 64, 64) * 0.1 + torch.tensor([0.0, 0.0, 0.8])[:, None, None]
        return pts, torch.randn(n, 4), torch.ones(n, 64, 64, dtype=torch.bool)

    pts, u, valid = batch(32)

    def train_step() -> None:
        pred = model(pts, u, valid, sigma=0.05, gamma=5.0).points
        loss = point_loss(pred, pts + 0.01, valid, pts)
        opt.zero_grad()
        loss.backward()
        opt.step()

    out: dict = {"train_step_ms_batch32": 1e3 * median_seconds(train_step, repeats=repeats)}
    out["infer_samples_per_s"] = {}
    model.eval()
    for n in (1, 64, 256):
        x = batch(n)

        def infer(x: tuple[torch.Tensor, ...] = x) -> None:
            with torch.inference_mode():
                model(*x)

        reps = max(3, repeats // (1 + n // 64))
        out["infer_samples_per_s"][str(n)] = n / median_seconds(infer, repeats=reps)
    return out


def _bench_state(device: str = "cpu") -> tuple:
    """The planner bench's scenario, world, state (single_box, pusher near the box) and
    goal."""
    import torch

    from planner import plan_state
    from scenarios import load_scenario
    from sim import PushWorld

    scenario = load_scenario("single_box")
    world = PushWorld(scenario)
    obs = world.reset(3)
    for _ in range(4):  # bring the pusher near the box
        d = obs.object_poses[0, :2] - obs.pusher_xy_m
        obs = world.step(0.12 * d / np.linalg.norm(d))
    goal = torch.tensor([*(obs.object_poses[0, :2] + [0.1, 0.05]), 0.5])
    return scenario, world, plan_state(obs, world), goal


def replan_breakdown(
    replan_ms: float, *, repeats: int, device: str = "cpu", model: str | None = None
) -> dict[str, float]:
    """Where a default replan (cem with the shipped SE3-Net) spends its time, in ms per
    replan: each piece timed alone at the batch each iteration runs it at (the population
    shrinks), times the number of calls; "optimiser and rest" is ``replan_ms``, the default
    replan measured in the planner table, less their sum."""
    import torch

    from planner import PlannerConfig, PushCost, make_dynamics
    from planner.dynamics import planar_fit
    from se3net.model import transform_layer
    from se3net.se3 import params_to_transform

    scenario, world, state, goal = _bench_state(device)
    cfg = PlannerConfig()
    H = cfg.steps(scenario.action.dt_control_s)
    dyn = make_dynamics("se3net", scenario, model=model, device=device)
    net, bb = dyn.model, dyn.model.backbone
    cost = PushCost(scenario, goal)
    x1, valid, obj = (x[None] for x in dyn.network_view(state))
    sel = obj.flatten().nonzero()[:, 0]

    def timed(fn) -> float:
        def run() -> None:
            with torch.inference_mode():
                fn()

        return 1e3 * median_seconds(run, repeats=repeats)

    def pieces(K: int) -> dict[str, tuple[int, Callable[[], object]]]:
        """(calls per iteration, timed call) of each piece at a population of K."""
        xK, validK = x1.expand(K, -1, -1, -1).contiguous(), valid.expand(K, -1, -1)
        u, U = torch.zeros(K, 4, device=device), torch.zeros(K, H, 2)
        with torch.inference_mode():
            enc1, encK = net.encode(x1, valid), net.encode(xK, validK)
            code = bb.code(encK, net.norm.controls(u))
            masks = torch.softmax(bb.decode(code, encK), 1)
            T = params_to_transform(net.se3_head(code).view(K, -1, 6))
            src = xK.flatten(2)[0, :, sel].T[:, :2]
            dst = xK.flatten(2)[:, :, sel].transpose(1, 2)[..., :2]
            rollout = dyn.rollout(state, U)
        return {
            "encoder, observed cloud (batch 1)": (1, lambda: net.encode(x1, valid)),
            "encoder, predicted clouds": (H - 1, lambda: net.encode(xK, validK)),
            "mask decoder": (H, lambda: bb.decode(code, enc1)),
            "SE(3) head": (H, lambda: params_to_transform(
                net.se3_head(bb.code(enc1, net.norm.controls(u))).view(K, -1, 6))),
            "transform layer": (H, lambda: transform_layer(xK, validK, masks, T)),
            "pose fit": (H, lambda: planar_fit(src, dst, src.mean(0))),
            "cost": (1, lambda: cost.cost(state, rollout, U, last_action=torch.zeros(2))),
            FRONT: (1, lambda: front.cost(state, rollout, U, last_action=torch.zeros(2))),
        }  # fmt: skip

    # the bench's pusher is behind the box, where the keep-out term is not computed; a goal
    # beyond the pusher puts it in front of the box, where it is (timed apart, not in the sum)
    FRONT = "cost with the keep-out term computed (not in the sum)"
    away = state.pusher_xy - state.object_pose[:2]
    front = PushCost(scenario, torch.cat([state.object_pose[:2] + 0.1 * away / away.norm(),
                                          goal[2:]]))  # fmt: skip
    assert not front.is_behind(state)
    out: dict[str, float] = {}
    kept = round(cfg.keep_elites * cfg.elites)
    for it in range(cfg.iterations):
        K = cfg.population(it) + (kept if it == 0 else 0)
        for name, (calls, fn) in pieces(K).items():
            out[name] = out.get(name, 0.0) + calls * timed(fn)
    front_ms = out.pop(FRONT)
    out["optimiser and rest"] = replan_ms - sum(out.values())
    out["replan"] = replan_ms
    out[FRONT] = front_ms
    return out


def _planning_dynamics(scenario, model: str | None, device: str = "cpu"):
    """The SE3-Net backend as the planner runs it by default: predictions fed back rendered,
    motion counted only within reach of touch (``PushConfig``'s defaults)."""
    from planner import PlanSettings, make_dynamics

    rollout = PlanSettings().rollout
    return make_dynamics("se3net", scenario, model=model, device=device, feedback=rollout.feedback,
                         contact_margin_m=rollout.contact_margin_m)  # fmt: skip


def _side_by_side_replan(repeats: int, model: str | None, planning: bool) -> float:
    """One of several processes timing default replans at once (1 torch thread each), with
    the backend's defaults or (``planning``) the planner's."""
    import torch

    from planner import PlanSettings, PushCost, make_dynamics, make_planner

    torch.set_num_threads(1)
    scenario, world, state, goal = _bench_state()
    dyn = (
        _planning_dynamics(scenario, model)
        if planning
        else make_dynamics("se3net", scenario, model=model)
    )
    planner = make_planner("cem", dyn, PushCost(scenario, goal), scenario, PlanSettings().optimiser)
    return 1e3 * median_seconds(lambda: planner.plan(state), repeats=repeats, warmup=1)


def bench_planner(
    *, repeats: int, model: str | None = None, flow_model: str | None = None, device: str = "cpu"
) -> dict:
    """Median replan time of each optimiser with each backend at the default settings, on a
    single_box state with the pusher near the box; where the default replan's time goes; the
    default replan in two processes side by side; the same two for cem with the SE3-Net as
    the planner runs it by default (``planner_default``: fed back rendered, the contact
    gate); and the SE3-Net rollout's
    candidate-steps/s (K = samples, H = horizon of the default config). ``model``: the
    SE3-Net checkpoint timed (default: the shipped one)."""
    import torch

    from planner import PLANNERS, PlanSettings, PushCost, make_dynamics, make_planner
    from scenarios import InputError
    from se3net.checkpoint import model_config
    from se3net.device import check_device
    from sim.jobs import Backend, run_jobs
    from sim.shards import portable_path

    check_device(device)  # before anything is timed
    if model is not None and model_config(model).is_flow:
        raise InputError(f"--model {model} is a flow net; time it with --flow-model")
    if flow_model is not None and not model_config(flow_model).is_flow:
        raise InputError(f"--flow-model {flow_model} is not a flow net; time it with --model")
    scenario, world, state, goal = _bench_state(device)
    cfg = PlanSettings().optimiser  # the default planner's
    backends = {"se3net": model, "oracle": None, "no-motion": None}
    if flow_model:
        backends["flow"] = flow_model
    times: dict[str, float | None] = {}
    for backend, ckpt in backends.items():
        kind = "flow" if backend == "flow" else backend
        dyn = make_dynamics(kind, scenario, model=ckpt, device=device, world=world)
        for name in PLANNERS:
            key = f"{name}/{backend}"
            if name in ("grad", "sqp") and not dyn.differentiable:
                times[key] = None  # not applicable: the simulator has no gradients
                continue
            planner = make_planner(name, dyn, PushCost(scenario, goal), scenario, cfg)
            n = max(3, repeats // 4) if backend == "oracle" or name in ("grad", "sqp") else repeats
            times[key] = 1e3 * median_seconds(lambda p=planner: p.plan(state), repeats=n, warmup=2)
    dyn = make_dynamics("se3net", scenario, model=model, device=device)
    H = cfg.steps(scenario.action.dt_control_s)
    U = torch.zeros(cfg.samples, H, 2)

    def rollout() -> None:
        with torch.inference_mode():
            dyn.rollout(state, U)

    steps_per_s = cfg.samples * H / median_seconds(rollout, repeats=repeats)
    breakdown = replan_breakdown(times["cem/se3net"], repeats=repeats, device=device, model=model)
    side_by_side = Backend(workers=2)
    pair = list(run_jobs(_side_by_side_replan, [(repeats, model, False)] * 2, side_by_side))
    planning = make_planner("cem", _planning_dynamics(scenario, model, device),
                            PushCost(scenario, goal), scenario, cfg)  # fmt: skip
    planned_ms = 1e3 * median_seconds(lambda: planning.plan(state), repeats=repeats, warmup=2)
    planned_pair = list(run_jobs(_side_by_side_replan, [(repeats, model, True)] * 2, side_by_side))
    return {
        "se3net_model": portable_path(model) if model else "default",
        "replan_ms_median": times,
        "default": "cem/se3net",
        "default_replan_breakdown_ms": breakdown,
        "default_replan_ms_two_processes": float(np.median(pair)),
        "planner_default": {
            "replan_ms_median": planned_ms,
            "replan_ms_two_processes": float(np.median(planned_pair)),
        },
        "se3net_rollout_candidate_steps_per_s": steps_per_s,
        "settings": {"samples": cfg.samples, "horizon_steps": H, "iterations": cfg.iterations},
    }


SAMPLERS = {
    "cem 48x3 (v0 default)": {
        "samples": 48, "elites": 6, "colour": 0.0, "shrink": 1.0, "keep_elites": 0.0,
        "warm_std": None,
    },
    "cem 24x3": {
        "samples": 24, "elites": 4, "colour": 0.0, "shrink": 1.0, "keep_elites": 0.0,
        "warm_std": None,
    },
    "icem 32/1.25, colour 0.5, 6 elites (default)": {
        "samples": 32, "elites": 6, "shrink": 1.25, "keep_elites": 0.3, "warm_std": 0.25,
        "colour": 0.5,
    },
    "icem 24/1.25, colour 0.5": {
        "samples": 24, "elites": 4, "shrink": 1.25, "keep_elites": 0.3, "warm_std": 0.25,
        "colour": 0.5,
    },
    "icem 24/1.25, white noise": {
        "samples": 24, "elites": 4, "shrink": 1.25, "keep_elites": 0.3, "warm_std": 0.25,
        "colour": 0.0,
    },
    "icem 16x3, colour 0.5": {
        "samples": 16, "elites": 4, "shrink": 1.0, "keep_elites": 0.5, "warm_std": 0.25,
        "colour": 0.5,
    },
}  # fmt: skip
"""the CEM settings ``bench sampling`` compares (PlannerConfig fields over the defaults)"""


def bench_sampling(*, repeats: int, pushes: int = 3, steps: int = 16) -> dict:
    """Plan quality against rollouts for CEM settings, with the shipped SE3-Net on single_box.

    States come from ``pushes`` closed loops of ``steps`` steps (the default planner, trial
    seed 7, which no trial table uses); each setting replans along them in order,
    warm-starting itself, one torch thread. At every state a strong CEM (128 samples, 12
    elites, 6 iterations, over the defaults), starting from the setting's warm start and last
    action (its own kept elites aside), plans too; a setting's excess cost is its plan's
    cost over the better of the two, relative to the strong plan's (0: as good).
    """
    import dataclasses

    import torch
    from tqdm import tqdm

    from evaluation.trials import draw_trial
    from planner import PlannerConfig, PushCost, make_dynamics, make_planner, plan_state
    from scenarios import load_scenario
    from sim import PushWorld
    from sim.jobs import torch_threads

    scenario = load_scenario("single_box")
    dyn = make_dynamics("se3net", scenario)
    reference = PlannerConfig(samples=128, elites=12, iterations=6)
    out: dict = {}
    with torch_threads(1):
        runs = []
        for i in range(pushes):
            trial = draw_trial(scenario, 7, i)
            world = PushWorld(scenario)
            obs = world.reset(trial["reset_seed"])
            goal = torch.tensor(trial["goal"])
            planner = make_planner("cem", dyn, PushCost(scenario, goal), scenario,
                                   PlannerConfig(seed=i))  # fmt: skip
            states = []
            for _ in range(steps):
                states.append(plan_state(obs, world))
                obs = world.step(planner.plan(states[-1])[0])
            runs.append((goal, states))
        for name, fields in tqdm(SAMPLERS.items(), desc="samplers"):
            cfg = PlannerConfig(**fields)
            excess, ms = [], []
            for i, (goal, states) in enumerate(runs):
                cost = PushCost(scenario, goal)
                planner = make_planner("cem", dyn, cost, scenario, dataclasses.replace(cfg, seed=i))
                strong = make_planner("cem", dyn, cost, scenario,
                                      dataclasses.replace(reference, seed=i))  # fmt: skip
                for state in states:
                    strong.nominal = planner.nominal.clone()
                    strong.last_action = planner.last_action.clone()
                    _, info = planner.plan(state)
                    ms.append(info.wall_ms)
                    ref = strong.plan(state)[1].cost
                    excess.append((info.cost - min(ref, info.cost)) / max(ref, 1e-9))
            out[name] = {
                "candidates_per_replan": sum(cfg.population(k) for k in range(cfg.iterations)),
                "replan_ms_median_1_thread": float(np.median(ms)),
                "excess_cost_median": float(np.median(excess)),
                "excess_cost_mean": float(np.mean(excess)),
                "excess_cost_p90": float(np.quantile(excess, 0.9)),
            }
    return out


def bench_ddp(*, repeats: int, device: str = "cpu", iters: int = 60, batch: int = 32) -> dict:
    """``se3push train`` under ``torchrun`` with 1 and 2 processes (gloo on CPU, one torch
    thread each; NCCL on CUDA, one GPU each, as many as there are): examples/s of the training
    loop (median over runs, the final validation included) and the validation loss after the
    same ``iters * batch`` examples (the batch is the total over the processes), on 40 episodes
    of ``single_box`` (64x64, the shipped model's setting)."""
    import os
    import subprocess
    import sys
    import tempfile

    import torch

    from se3net.device import check_device
    from sim.dataset import DataConfig, generate

    check_device(device)
    cuda = device.startswith("cuda")
    counts = tuple(range(1, min(2, torch.cuda.device_count()) + 1)) if cuda else (1, 2)
    runs = max(1, min(repeats, 3))
    # load_average_before: what else ran on the machine (1-minute load average)
    out: dict = {"device": device, "iters": iters, "batch": batch, "examples": iters * batch,
                 "cpus": os.cpu_count(), "runs": runs,
                 "load_average_before": os.getloadavg()[0]}  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        generate(DataConfig("single_box", episodes=40), data, workers=2, progress=False)
        for n in counts:
            rates, losses, mses = [], [], []
            for r in range(runs):
                run = Path(tmp) / f"run_{n}_{r}"
                cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone",
                       "--nproc_per_node", str(n), "-m", "se3push", "train", "--data", str(data),
                       "--out", str(run), "--iters", str(iters), "--batch", str(batch),
                       "--eval-every", str(iters), "--device", device]  # fmt: skip
                env = {**os.environ, "OMP_NUM_THREADS": "1"}
                subprocess.run(cmd, check=True, capture_output=True, env=env)
                last = json.loads((run / "metrics.jsonl").read_text().splitlines()[-1])
                rates.append(iters * batch / last["elapsed_s"])
                losses.append(last["val_loss"])
                mses.append(last["val_flow_mse_cm2"])
            key = "1_process" if n == 1 else f"{n}_processes"
            out[f"examples_per_s_{key}"] = float(np.median(rates))
            out[f"val_loss_{key}"] = float(np.median(losses))
            out[f"val_flow_mse_cm2_{key}"] = float(np.median(mses))
    if len(counts) > 1:
        out["speedup_2_vs_1"] = out["examples_per_s_2_processes"] / out["examples_per_s_1_process"]
    return out


from se3push.bench_horizon import bench_horizon  # noqa: E402 (its helpers are above)

BENCHES: dict[str, Callable[..., dict[str, float]]] = {
    "world": bench_world,
    "data": bench_data,
    "model": bench_model,
    "planner": bench_planner,
    "sampling": bench_sampling,
    "ddp": bench_ddp,
    "horizon": bench_horizon,
}


def run_bench(what: str, *, repeats: int, json_path: str | None, **options: object) -> dict:
    """Run one benchmark, print its table and optionally write its figures as JSON (the
    settings are checked, and the JSON's folder made, before anything is timed)."""
    from scenarios import InputError
    from sim.shards import atomic_write_bytes

    if repeats < 1:
        raise InputError(f"--repeats must be at least 1, got {repeats}")
    if json_path:
        if Path(json_path).is_dir():
            raise InputError(f"--json {json_path} is a folder; give the JSON file's path")
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
    figures = BENCHES[what](repeats=repeats, **options)
    flat = {
        f"{name}[{key}]" if isinstance(value, dict) else name: v
        for name, value in figures.items()
        for key, v in (value.items() if isinstance(value, dict) else [(None, value)])
    }
    width = max(map(len, flat))
    print(f"se3push bench {what} (medians over repeats)")
    for name, value in flat.items():
        shown = (
            (f"{value:12.1f}" if abs(value) >= 100 else f"{value:12.4g}")
            if isinstance(value, float)
            else f"{'n/a' if value is None else value:>12}"
        )
        print(f"  {name:<{width}}  {shown}")
    if json_path:
        atomic_write_bytes(Path(json_path), (json.dumps(figures, indent=2) + "\n").encode())
    return figures
