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

    def control_step() -> None:
        nonlocal world
        if world.observe().done:
            world.reset(int(rng.integers(1 << 30)))
        world.step(rng.uniform(-0.1, 0.1, size=2))

    out["control_steps_per_s"] = 1.0 / median_seconds(control_step, repeats=repeats * 5)
    return out


BENCHES: dict[str, Callable[..., dict[str, float]]] = {"world": bench_world}


def run_bench(what: str, *, repeats: int, json_path: str | None) -> dict[str, float]:
    """Run one benchmark, print its table and optionally write its figures as JSON."""
    figures = BENCHES[what](repeats=repeats)
    width = max(map(len, figures))
    print(f"se3push bench {what} (medians over repeats)")
    for name, value in figures.items():
        print(f"  {name:<{width}}  {value:12.1f}")
    if json_path:
        Path(json_path).write_text(json.dumps(figures, indent=2) + "\n")
    return figures
