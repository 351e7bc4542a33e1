"""Planner-visited data (data aggregation, as model-based RL does): ``se3push improve``.

Each round runs closed-loop pushes with the current model in each of its scenarios, with some
exploration noise on the executed actions, records every executed step as training episodes in
the dataset format (the same exact associations as exploration data: they are the world's own
observations), pools them with all data so far, fine-tunes the model on the pool, and measures
it on a fixed held-out trial set per scenario that no round ever trains on. Scenarios named
``measure_only`` are measured every round and never collected in (objects held out of training).

Layout of ``out``::

    config.json                  the run's settings (a rerun must match them)
    round_0/heldout/<scenario>/  trials of the starting model on each held-out set
    round_R/data/<scenario>/     the round's planner-visited episodes (a dataset folder each)
    round_R/model/               the fine-tuning run (best.pt is the round's model)
    round_R/heldout/<scenario>/  trials of that model on each held-out set
    improve.json, improve.md, improve.png

Every step of a round is kept when done (complete dataset, training checkpoints, trial
lines), so an interrupted run started again continues where it stopped.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.records import SCHEMA, migrate_config
from evaluation.report import summary_cells
from evaluation.trials import TrialsConfig, draw_trial, run_trials, worker_backend
from planner.loop import PushConfig, push_scenario, run_push
from planner.settings import PlanSettings
from scenarios import InputError, check_seed, load_scenario
from scenarios.config import differences, scenario_dict
from sim.dataset import (
    CONTROL_LAYOUT,
    DATA_FORMAT,
    MANIFEST,
    PLANNER_MODE,
    EpisodeRecorder,
    episode_stats,
    merge_stats,
)
from sim.folders import writes_folder
from sim.jobs import Backend, run_jobs
from sim.shards import atomic_write_bytes, atomic_write_json, portable_path, write_shard

COLLECT_STREAM = 1_000_003
"""collection trials of round r are drawn from seed ``seed * COLLECT_STREAM + r``: a trial
stream apart from the held-out set's (seed ``seed``)"""


@dataclass(frozen=True)
class ImproveConfig:
    """Rounds of planner-visited data collection and fine-tuning."""

    scenarios: tuple[str, ...]
    """scenario names or TOML paths: collected in and measured on every round"""
    model: str
    """the starting checkpoint (round 0)"""
    data: tuple[str, ...]
    """the exploration datasets the starting model was trained on (pooled in every round)"""
    measure_only: tuple[str, ...] = ()
    """scenarios measured every round but never collected in (objects held out of training)"""
    rounds: int = 3
    trials_per_round: int = 20
    """closed-loop pushes recorded per round in each of ``scenarios``"""
    heldout: int = 50
    """held-out trials per scenario (never trained on) on which every round is measured"""
    seed: int = 0
    """seed of the held-out trial set; the collection trials come from other streams"""
    action_noise: float = 0.1
    """SD of the noise on executed actions while collecting, as a fraction of the bound"""
    finetune_iters: int = 1000
    lr: float = 3e-4
    visited_fraction: float = 0.5
    """share of each fine-tuning batch drawn from the planner-visited data: the rounds add a
    few hundred steps beside tens of thousands of exploration steps, which uniform sampling
    would hardly show the model"""
    batch: int = 32
    eval_every: int = 250
    max_steps: int = 60
    """control steps per push, collected or held out"""
    plan: PlanSettings = PlanSettings()
    """the planning settings of every push (optimiser, cost, rollout)"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        for name in ("scenarios", "data", "measure_only"):  # one name or path stands for one
            value = getattr(self, name)
            object.__setattr__(self, name, (value,) if isinstance(value, str) else tuple(value))
        if not self.scenarios or not self.data:
            raise InputError("improve needs at least one --scenario and one --data folder")
        positive = ("rounds", "trials_per_round", "heldout", "finetune_iters", "max_steps",
                    "batch", "eval_every")  # fmt: skip
        for name in positive:  # here, not in the fine-tuning: before round 0 runs
            if getattr(self, name) < 1:
                raise InputError(
                    f"--{name.replace('_', '-')} must be positive, got {getattr(self, name)}"
                )
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise InputError(f"--lr must be a positive number, got {self.lr}")

        if not 0.0 <= self.action_noise <= 1.0:
            raise InputError(f"action noise must be in [0, 1], got {self.action_noise}")
        if not 0.0 <= self.visited_fraction < 1.0:
            raise InputError(f"--visited-fraction must be in [0, 1), got {self.visited_fraction}")

    def collect_seed(self, r: int) -> int:
        return self.seed * COLLECT_STREAM + r

    def measured(self) -> tuple[str, ...]:
        """Every scenario the rounds are measured on: the collected ones, then the others."""
        return (*self.scenarios, *self.measure_only)


def config_record(cfg: ImproveConfig) -> dict[str, Any]:
    """What an improve run's ``config.json`` holds (``evaluation.records``, today's schema)."""
    return {"schema": SCHEMA, **asdict(cfg), "retired": {}}


def record_trial(
    cfg: ImproveConfig, scenario: str, model: str, r: int, i: int, steps_per_episode: int
) -> dict:
    """Collection trial i of round r in ``scenario``: push with ``model`` and noisy actions;
    returns the executed steps cut into episodes of ``steps_per_episode`` and the trial's reset
    seed."""
    trial = draw_trial(load_scenario(scenario), cfg.collect_seed(r), i)
    episodes: list[dict[str, np.ndarray]] = []
    current: dict[str, Any] = {}

    def start(world, obs) -> None:
        # the world counts QP failures since its reset: each episode keeps its own share
        current.update(world=world, rec=EpisodeRecorder(world, steps_per_episode, obs),
                       qp_before=world.qp_failures)  # fmt: skip

    def finish() -> None:
        episodes.append(current["rec"].finish(current["world"].qp_failures - current["qp_before"]))

    def on_transition(world, obs, action) -> None:
        if action is None:
            start(world, obs)
            return
        if obs.done:  # the frame where the episode ended is dropped, as exploration data does
            return
        rec = current["rec"]
        rec.step(action, PLANNER_MODE, obs)
        if rec.full:
            finish()
            start(world, obs)

    push = PushConfig(
        goal=tuple(trial["goal"]), scenario=scenario, model=model, seed=trial["reset_seed"],
        max_steps=cfg.max_steps, action_noise=cfg.action_noise, plan=cfg.plan,
    )  # fmt: skip
    result = run_push(push, on_transition=on_transition)
    if current["rec"].length > 0:
        finish()
    return {"reset_seed": trial["reset_seed"], "episodes": episodes, **result.summary()}


def collect(
    cfg: ImproveConfig, scenario: str, model: str, r: int, out: Path, *, jobs: Backend
) -> dict:
    """Record round r's closed-loop pushes in ``scenario`` as a dataset folder ``out``, the
    trials run on ``jobs``; returns its manifest."""
    from tqdm import tqdm

    from sim.datastore import read_manifest
    from sim.world import PushWorld

    if (out / MANIFEST).exists():
        manifest = json.loads((out / MANIFEST).read_text())
        if manifest.get("complete"):
            return manifest
    base = read_manifest(cfg.data[0])["identity"]
    T = base["steps_per_episode"]
    world_cfg = load_scenario(scenario)
    heldout = {draw_trial(world_cfg, cfg.seed, i)["reset_seed"] for i in range(cfg.heldout)}
    args = [(cfg, scenario, model, r, i, T) for i in range(cfg.trials_per_round)]
    bar = tqdm(total=len(args), unit="trial", desc=f"round {r}: collect in {world_cfg.name}")
    trials = []
    # in order: the bytes do not depend on the backend or the number of workers
    for t in run_jobs(record_trial, args, jobs, ordered=True):
        trials.append(t)
        bar.update(1)
    bar.close()
    leaked = [t["reset_seed"] for t in trials if t["reset_seed"] in heldout]
    if leaked:
        raise RuntimeError(f"collection trials {leaked} coincide with held-out trials")
    episodes = [ep for t in trials for ep in t["episodes"]]
    if not episodes:
        raise RuntimeError(f"round {r} recorded no steps; raise --max-steps or --trials-per-round")
    arrays = {k: np.stack([ep[k] for ep in episodes]) for k in episodes[0]}
    arrays["episode_index"] = np.arange(len(episodes), dtype=np.int64)
    out.mkdir(parents=True, exist_ok=True)
    digest = write_shard(out / "shard_00000.npz", arrays)
    T_cam_world = PushWorld(world_cfg).camera.T_cam_world
    stats = merge_stats([episode_stats(ep, T_cam_world) for ep in episodes])
    stats["episodes"] = len(episodes)
    identity = {
        **base,
        "scenario": json.loads(json.dumps(scenario_dict(world_cfg))),
        "seed": cfg.collect_seed(r),
        "episodes": len(episodes),
        "episodes_per_shard": len(episodes),
        "exploration": {
            "modes": [PLANNER_MODE],
            "model": model,
            "planner": cfg.plan.planner,
            "action_noise": cfg.action_noise,
            "round": r,
            "trials": cfg.trials_per_round,
        },
    }
    if identity["control_layout"] != list(CONTROL_LAYOUT) or identity["format"] != DATA_FORMAT:
        raise InputError(
            f"{cfg.data[0]} was written by another version of this code; regenerate it"
        )
    manifest = {
        "identity": identity,
        "shards": {"shard_00000.npz": {"sha256": digest, **stats}},
        "stats": stats,
        "collection": [
            {k: v for k, v in t.items() if k not in ("episodes", "per_step")} for t in trials
        ],  # fmt: skip
        "complete": True,
    }
    atomic_write_json(out / MANIFEST, manifest)
    return manifest


def finetune(cfg: ImproveConfig, init: str, data: list[str], out: Path) -> str:
    """Fine-tune ``init`` on the pooled ``data`` (the exploration folders first, then the
    planner-visited ones) into ``out``, the same network; returns the best checkpoint."""
    from se3net.checkpoint import model_config
    from se3net.train import TrainConfig, train

    net = model_config(init)
    tcfg = TrainConfig(
        data=tuple(data), out=str(out), variant=net.variant, k=net.k, stride=net.stride,
        iters=cfg.finetune_iters, batch=cfg.batch,
        lr=cfg.lr, seed=cfg.seed, eval_every=min(cfg.eval_every, cfg.finetune_iters),
        init=init, later_fraction=cfg.visited_fraction,
        later_from=len(cfg.data),
    )  # fmt: skip
    train(tcfg, resume=(out / "last.pt").exists())
    return str(out / "best.pt")


@writes_folder(lambda a: a.arguments["out"])
def run_improve(
    cfg: ImproveConfig,
    out: str | Path,
    *,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
) -> dict[str, Any]:
    """Run (or continue) the rounds, the closed-loop pushes on ``workers`` workers of
    ``backend`` (``sim.jobs``: the local pool, or Ray at ``address``); returns and writes the
    per-round, per-scenario table."""
    from se3net.checkpoint import load_checkpoint, model_config
    from sim.datastore import read_manifest, scenario_of

    jobs = worker_backend(workers, None, backend, address)
    model_config(cfg.model)  # a network the rounds can fine-tune (a pose model is refused)
    # refuse what cannot work before writing anything
    measured = [push_scenario(s) for s in cfg.measured()]
    names = [s.name for s in measured]
    if len(set(names)) < len(names):
        raise InputError(f"improve measures each scenario once; got {', '.join(names)}")
    for scenario in measured:
        load_checkpoint(cfg.model, scenario=scenario)
    for d in cfg.data:
        load_checkpoint(cfg.model, scenario=scenario_of(read_manifest(d)))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = out / "config.json"
    if meta.exists():
        # in today's schema (runs from before a setting ran as the code did before it)
        old = migrate_config(json.loads(meta.read_text()))
        new = json.loads(json.dumps(config_record(cfg)))
        old.pop("rounds", None), new.pop("rounds")  # more rounds continue a run
        if old != new:
            raise InputError(
                f"{out} holds another improve run ({'; '.join(differences(old, new))}); "
                "use a new --out folder"
            )
    atomic_write_json(meta, config_record(cfg))

    def heldout(model: str, r: int) -> list[dict[str, Any]]:
        rows = []
        for scenario, name in zip(cfg.measured(), names, strict=True):
            tcfg = TrialsConfig(
                scenario=scenario, n=cfg.heldout, model=model, seed=cfg.seed,
                max_steps=cfg.max_steps, plan=cfg.plan,
            )  # fmt: skip
            summary = run_trials(tcfg, out / f"round_{r}" / "heldout" / name, workers=workers,
                                 backend=backend, address=address)  # fmt: skip
            figures = {k: v for k, v in summary.items() if k != "config"}
            rows.append({"round": r, "scenario": name, "model": portable_path(model), **figures})
        return rows

    rows = heldout(cfg.model, 0)
    model, data = cfg.model, list(cfg.data)
    for r in range(1, cfg.rounds + 1):
        new_episodes = {}
        for scenario, name in zip(cfg.scenarios, names[: len(cfg.scenarios)], strict=True):
            folder = out / f"round_{r}" / "data" / name
            manifest = collect(cfg, scenario, model, r, folder, jobs=jobs)
            data.append(str(folder))
            new_episodes[name] = manifest["identity"]["episodes"]
        model = finetune(cfg, model, data, out / f"round_{r}" / "model")
        rows += [
            {**row, "new_episodes": new_episodes.get(row["scenario"], 0)}
            for row in heldout(model, r)
        ]
    paths = {"model": portable_path(cfg.model), "data": [portable_path(d) for d in cfg.data]}
    result = {"config": {**asdict(cfg), **paths}, "rounds": rows}
    atomic_write_json(out / "improve.json", result)
    atomic_write_bytes(out / "improve.md", table_markdown(rows).encode())
    plot_rounds(rows, out / "improve.png")
    return result


def table_markdown(rows: list[dict[str, Any]]) -> str:
    """Success and diagnostics per round and scenario on the held-out trials."""
    lines = [
        "| round | scenario | new episodes | success 2 cm/10° [95 % CI] | success 5 cm/20° | "
        "phantom | missed | progress ratio | median steps | other objects moved |",
        "|---" * 10 + "|",
    ]
    for r in rows:
        c = summary_cells(r)
        lines.append(
            f"| {r['round']} | {r['scenario']} | {r.get('new_episodes', '–')} | {c['tight']} | "
            f"{r['success_loose']:.0%} | {c['phantom']} | {c['missed']} | {c['progress']} | "
            f"{r['median_steps']:.0f} | {c['disturbance']} |"
        )
    return "\n".join(lines) + "\n"


def plot_rounds(rows: list[dict[str, Any]], out: Path) -> None:
    """Per scenario against the round: success (tight, with its interval, and loose), the
    diagnostics with their aims (phantom and missed motion under 5 %), and the predicted/actual
    progress (aim 0.8-1.25)."""
    from sim.render import pyplot, save_figure

    plt = pyplot()
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(15, 4))
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))

    def diag(sub: list[dict[str, Any]], key: str) -> np.ndarray:
        return np.array(
            [np.nan if r["diagnostics"][key] is None else r["diagnostics"][key] for r in sub]
        )

    for j, name in enumerate(scenarios):
        sub = [r for r in rows if r["scenario"] == name]
        x = [r["round"] + 0.05 * (j - (len(scenarios) - 1) / 2) for r in sub]
        colour = f"C{j}"
        y = np.array([r["success_tight"] for r in sub])
        ci = np.array([r["success_tight_ci95"] for r in sub])
        a.errorbar(x, y, yerr=[y - ci[:, 0], ci[:, 1] - y], marker="o", capsize=3, color=colour,
                   label=f"{name}, 2 cm & 10°")  # fmt: skip
        a.plot(x, [r["success_loose"] for r in sub], ls="--", marker=".", color=colour,
               label=f"{name}, 5 cm & 20°")  # fmt: skip
        b.plot(x, 100 * diag(sub, "phantom_rate"), marker="o", color=colour,
               label=f"{name}, phantom")  # fmt: skip
        b.plot(x, 100 * diag(sub, "missed_rate"), marker="s", ls="--", color=colour,
               label=f"{name}, missed")  # fmt: skip
        c.plot(x, diag(sub, "progress_ratio"), marker="^", color=colour, label=name)
    a.set_ylabel("held-out success")
    a.set_ylim(-0.05, 1.05)
    b.axhline(5.0, color="grey", ls=":", lw=0.8)
    b.set_ylabel("% of executed steps (aim < 5 %)")
    worst = np.nanmax(
        np.concatenate([100 * diag(rows, "phantom_rate"), 100 * diag(rows, "missed_rate"), [0.0]])
    )
    b.set_ylim(0, max(10.0, worst + 1))
    c.axhspan(0.8, 1.25, color="green", alpha=0.08)
    c.set_ylabel("predicted/actual progress (aim 0.8-1.25)")
    c.set_ylim(0, 2)
    rounds = sorted({r["round"] for r in rows})
    for ax in (a, b, c):
        ax.set_xlabel("round")
        ax.set_xticks(rounds)
        ax.legend(fontsize=7)
    fig.suptitle("planner-visited data: held-out trials per round")
    save_figure(fig, out)
