"""How model accuracy relates to planning success.

For each model (checkpoints from different points of training, the variants, and the
``oracle`` and ``no-motion`` backends as the two ends) a study measures, on the same held-out
data and the same trial set:

- one-step flow MSE and its ratio to no-motion (the paper's metric);
- the pushed object's pose error after the planning horizon when the model is rolled forward
  exactly as the planner rolls it (each prediction fed back, the pusher integrated from the
  commands, the pose fitted to the predicted points), over held-out windows where the object
  moves: what the planner's cost actually sees;
- mask quality (binariness, IoU with the true parts);
- closed-loop success at both tolerances, final errors, steps, and the exploitation
  diagnostics (``planner.diagnostics``).

The two ends are measured, not assumed, where the data allow: no-motion's flow is zero and
its "mask" is one rigid body, the oracle's flow is the true flow and its masks are the true
parts. The oracle's horizon pose error is zero by construction (it is the simulator, whose
predictions the tests check against the world to 1e-6); the data hold no simulator state to
re-run it from. Which accuracy measure predicts success is a Spearman rank correlation over
the models.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from evaluation.records import BEFORE
from evaluation.report import fmt, summary_cells
from evaluation.trials import TrialsConfig, run_trials, weights_of
from planner.dynamics import (
    CONTACT_MARGIN_M,
    PLAN_FEEDBACK,
    PlanState,
    make_dynamics,
)
from planner.settings import PlanSettings
from scenarios import InputError, check_seed
from sim.folders import writes_folder
from sim.shards import atomic_write_bytes, atomic_write_json

BACKEND_MODELS = ("oracle", "no-motion")
HORIZON_MOVED_M = 3e-3
"""a held-out window counts for the horizon error if the object moves more than this"""

ACCURACY = {
    # key: (label, lower is better)
    "ratio_to_no_motion": ("one-step flow MSE / no-motion", True),
    "horizon_pos_err_cm": ("horizon position error (cm)", True),
    "horizon_yaw_err_deg": ("horizon yaw error (deg)", True),
    "mask_binariness": ("mask binariness", False),
    "iou": ("mask IoU", False),
}
"""the accuracy measures a study correlates with success"""


@dataclass(frozen=True)
class StudyConfig:
    """A study of several models on one scenario."""

    scenario: str
    """scenario name or TOML path"""
    data: str
    """dataset folder whose test split gives the accuracy figures"""
    models: tuple[str, ...]
    """oracle, no-motion, default, or checkpoint paths; ``LABEL=PATH`` names a row"""
    trials: int = 30
    """closed-loop trials per model (the same set for every model)"""
    seed: int = 0
    """seed of the trial set"""
    max_steps: int = 60
    """control steps per trial"""
    max_examples: int = 1000
    """held-out one-step examples (and horizon windows) per model"""
    plan: PlanSettings = PlanSettings()
    """the planning settings of every push (optimiser, cost, rollout)"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        if len(self.models) < 1:
            raise InputError("--models needs at least one model")
        labels = [label for label, _ in parse_models(self.models)]
        if len(set(labels)) != len(labels):
            raise InputError(f"two models share a label in {labels}; name them with LABEL=PATH")
        folders = [folder_name(label) for label in labels]
        if len(set(folders)) != len(folders):
            raise InputError(
                f"two labels in {labels} name one folder ({', '.join(folders)}: '/' and '=' "
                "become '_'); name the models apart with LABEL=PATH"
            )
        if self.trials < 1 or self.max_examples < 1 or self.max_steps < 1:
            raise InputError(
                f"--trials, --max-examples and --max-steps must be positive, got {self.trials}, "
                f"{self.max_examples}, {self.max_steps}"
            )


def parse_models(models: tuple[str, ...] | list[str]) -> list[tuple[str, str]]:
    """(label, model) pairs: ``LABEL=PATH`` as given, else a label from the name or path."""
    from se3net.checkpoint import resolve_model

    out = []
    for m in models:
        if "=" in m:
            label, model = m.split("=", 1)
        elif m in BACKEND_MODELS or resolve_model(m) != Path(m):  # a shipped model by name
            label, model = m, m
        else:
            p = Path(m)
            label = p.parent.name if p.stem in ("best", "last") else f"{p.parent.name}/{p.stem}"
            model = m
        out.append((label, model))
    return out


def _moving_windows(ds, data, object_index: int, max_windows: int, split: str = "test"):
    """Up to ``max_windows`` evenly spaced windows of ``ds`` (a ``PushDataset`` of ``data``'s
    ``split``) where the object moves more than ``HORIZON_MOVED_M``: their indices, and the
    object's recorded poses at their two ends ((n,3) each)."""
    from se3net.data import evenly_spaced

    e, t = ds.items[:, 0], ds.items[:, 1]
    poses = ds.a["object_poses"][:, :, object_index]  # (episodes, frames, 3), as recorded
    start, end = poses[e, t], poses[e, t + ds.horizon]
    moving = np.flatnonzero(np.hypot(*(end - start)[:, :2].T) > HORIZON_MOVED_M)
    if len(moving) == 0:
        raise InputError(
            f"the {split} split of {data} has no window where object {object_index} moves "
            f"over {ds.horizon} steps; generate more data"
        )
    pick = moving[evenly_spaced(len(moving), max_windows)]
    return pick, start[pick], end[pick]


def _window_states(ds, pick: np.ndarray, start: np.ndarray, object_index: int):
    """For each picked window: the planner's state at its start (as ``plan_state`` would make
    it), its actions (1,H,2), and the pushed object's spec."""
    from sim import object_part
    from sim.dataset import episode_objects

    part_id = object_part(object_index)
    T_world_cam = torch.from_numpy(ds.camera.T_world_cam).float()
    for s in range(0, len(pick), 64):
        b = ds.batch(pick[s : s + 64])
        for j, i in enumerate(pick[s : s + 64]):
            obj = episode_objects(ds.a, ds.items[i, 0])[object_index]
            state = PlanState(
                points=b["points"][j],
                valid=b["valid"][j],
                object_mask=b["part"][j] == part_id,
                object_pose=torch.from_numpy(start[s + j]).float(),
                pusher_xy=b["u"][j, 0, 2:],
                T_world_cam=T_world_cam,
                footprint_radius_m=obj.footprint_radius_m,
                yaw_period_rad=obj.yaw_period_rad,
            )
            yield state, b["u"][j, None, :, :2], obj


def study_dynamics(model: str, scenario, feedback: str, contact_margin_m: float | None):
    """A study model as the planner rolls it: ``no-motion`` or an SE3-Net checkpoint."""
    if model == "no-motion":
        return make_dynamics("no-motion", scenario)
    return make_dynamics("se3net", scenario, model=model, feedback=feedback,
                         contact_margin_m=contact_margin_m)  # fmt: skip


@torch.no_grad()
def horizon_pose_error(
    model: str,
    data: str | Path,
    horizon: int,
    *,
    object_index: int = 0,
    max_windows: int = 500,
    feedback: str = PLAN_FEEDBACK,
    contact_margin_m: float | None = CONTACT_MARGIN_M,
) -> dict[str, float]:
    """Mean position (cm) and yaw (deg) error of the object's predicted pose after ``horizon``
    steps, over held-out windows where it moves, the model rolled as the planner rolls it
    (``feedback``, ``contact_margin_m``: as ``PushConfig``'s)."""
    from se3net.data import PushDataset
    from sim import pose_errors

    ds = PushDataset(data, split="test", horizon=horizon)
    pick, start, end = _moving_windows(ds, data, object_index, max_windows)
    if model == "oracle":  # the simulator itself (tested against the world to 1e-6)
        return {"horizon_pos_err_cm": 0.0, "horizon_yaw_err_deg": 0.0, "windows": len(pick)}
    dynamics = study_dynamics(model, ds.scenario, feedback, contact_margin_m)
    pos_err, yaw_err = [], []
    for k, (state, actions, obj) in enumerate(_window_states(ds, pick, start, object_index)):
        pred = dynamics.rollout(state, actions).object_poses[0, -1].numpy()
        pos, yaw = pose_errors(pred, end[k], obj.yaw_period_rad)
        pos_err.append(pos)
        yaw_err.append(yaw)
    return {
        "horizon_pos_err_cm": 100 * float(np.mean(pos_err)),
        "horizon_yaw_err_deg": float(np.mean(yaw_err)),
        "windows": len(pick),
    }


@torch.no_grad()
def backend_accuracy(model: str, data: str | Path, *, max_examples: int) -> dict[str, Any]:
    """One-step flow and mask figures of the two ends: no-motion (zero flow, one rigid body)
    and the oracle (the true flow, the true parts as masks)."""
    from se3net.data import PushDataset, evenly_spaced
    from se3net.metrics import FlowStats, MaskStats, true_flow

    ds = PushDataset(data, split="test", horizon=1)
    flow, masks = FlowStats(), MaskStats()
    n_parts = int(ds.a["T_world_part"].shape[2])
    idx = evenly_spaced(len(ds), max_examples)
    for s in range(0, len(idx), 64):
        b = ds.batch(idx[s : s + 64])
        target = b["target"][:, 0]
        if model == "oracle":
            pred = target
            m = torch.nn.functional.one_hot(b["part"].clamp_min(0), n_parts).permute(0, 3, 1, 2)
        else:
            pred = b["points"]
            m = torch.ones_like(b["part"])[:, None]
        flow.add(pred, b["points"], target, b["target_valid"][:, 0], true_flow(b, 0))
        masks.add(m.float(), b["part"], b["points"], target, true_flow(b, 0))
    return {
        "variant": model,
        "flow_mse_cm2": flow.mse_cm2,
        "ratio_to_no_motion": flow.ratio,
        "mask_binariness": masks.binariness,
        "iou": masks.iou,
    }


def model_accuracy(model: str, data: str | Path, *, max_examples: int) -> dict[str, Any]:
    """The one-step and mask figures of a checkpoint or backend on the test split."""
    if model in BACKEND_MODELS:
        return backend_accuracy(model, data, max_examples=max_examples)
    from se3net.evaluate import evaluate_checkpoint

    r = evaluate_checkpoint(model, data, max_examples=max_examples)
    return {
        "variant": r.variant,
        "flow_mse_cm2": r.flow_mse,
        "ratio_to_no_motion": r.ratio_to_no_motion,
        "mask_binariness": r.mask_binariness,
        "iou": r.iou,
    }


def rank_correlations(rows: list[dict[str, Any]], success_key: str = "success_tight") -> dict:
    """Spearman correlation of each accuracy measure with success over the models that have
    it, signed so that a measure that predicts success well is near +1 whatever its
    direction (lower-is-better measures are negated). None with fewer than three models or
    no variation."""
    from se3net.metrics import spearman

    out = {}
    for key, (_, lower_better) in ACCURACY.items():
        pairs = [(r[key], r[success_key]) for r in rows if r.get(key) is not None]
        x, y = np.array(pairs, dtype=float).reshape(-1, 2).T
        if len(pairs) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
            out[key] = None
            continue
        out[key] = spearman(-x if lower_better else x, y)
    return out


def measure_counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    """How many of the models have each accuracy measure (a flow net has no masks)."""
    return {k: sum(r.get(k) is not None for r in rows) for k in ACCURACY}


def finding(
    corr: dict[str, float | None],
    n_models: int,
    who: str = "models",
    covered: dict[str, int] | None = None,
) -> str:
    """The study's result in plain words (ties named together); a measure that ``covered``
    (:func:`measure_counts`) says only some models have is named with how many."""
    known = {k: v for k, v in corr.items() if v is not None}
    covered = covered or {}

    def name(k: str) -> str:
        n = covered.get(k, n_models)
        return ACCURACY[k][0] + ("" if n == n_models else f" (the {n} with one)")

    if not known:
        return f"Over {n_models} {who}: too few, or no variation in success, to rank the measures."
    top = max(known.values())
    best = [name(k) for k, v in known.items() if v > top - 1e-9]
    order = ", ".join(f"{name(k)} {v:+.2f}" for k, v in
                      sorted(known.items(), key=lambda kv: -kv[1]))  # fmt: skip
    verb = (
        "predicts closed-loop success best"
        if len(best) == 1
        else ("predict closed-loop success best, tied")
    )
    return (
        f"Over {n_models} {who}, {' and '.join(best)} {verb} "
        f"(Spearman rank correlation {top:+.2f}, signed so that +1 means the more accurate "
        f"model always succeeds more often). All measures: {order}."
    )


def table_markdown(rows: list[dict[str, Any]]) -> str:
    """One row per model, every figure of the study."""
    head = (
        "| model | flow MSE (cm²) | ratio to no-motion | horizon pos err (cm) | horizon yaw err "
        "(deg) | binariness | IoU | success 2 cm/10° [95 % CI] | success 5 cm/20° | median "
        "final err (cm / deg) | median steps | phantom | missed | progress ratio |"
    )
    lines = [head, "|---" * 14 + "|"]
    for r in rows:
        c = summary_cells(r)
        lines.append(
            f"| {r['label']} | {fmt(r['flow_mse_cm2'])} | {fmt(r['ratio_to_no_motion'])} | "
            f"{fmt(r['horizon_pos_err_cm'], '.2f')} | {fmt(r['horizon_yaw_err_deg'], '.1f')} | "
            f"{fmt(r['mask_binariness'])} | {fmt(r['iou'])} | "
            f"{c['tight']} | {r['success_loose']:.0%} | "
            f"{100 * r['median_final_pos_err_m']:.1f} / {r['median_final_yaw_err_deg']:.1f} | "
            f"{r['median_steps']:.0f} | {c['phantom']} | {c['missed']} | {c['progress']} |"
        )
    return "\n".join(lines) + "\n"


def plot_study(rows: list[dict[str, Any]], out: Path) -> None:
    """Success (with its 95 % interval) against each accuracy measure, a point per model."""
    from sim.render import pyplot, save_figure

    plt = pyplot()
    fig, axes = plt.subplots(1, len(ACCURACY), figsize=(4.2 * len(ACCURACY), 4), squeeze=False)
    for ax, (key, (label, lower_better)) in zip(axes[0], ACCURACY.items(), strict=True):
        for r in rows:
            if r.get(key) is None:
                continue
            lo, hi = r["success_tight_ci95"]
            p = r["success_tight"]
            ax.errorbar(r[key], p, yerr=[[p - lo], [hi - p]], fmt="o", capsize=3)
            ax.annotate(r["label"], (r[key], p), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")  # fmt: skip
        ax.set_xlabel(label + (" (lower is better)" if lower_better else ""))
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("success (2 cm, 10°)")
    fig.suptitle("closed-loop success against model accuracy, one point per model")
    save_figure(fig, out)


def folder_name(label: str) -> str:
    """The name of a study row's trials folder and accuracy cache."""
    return label.replace("/", "_").replace("=", "_")


@writes_folder(lambda a: a.arguments["out"])
def run_study(cfg: StudyConfig, out: str | Path, *, workers: int = 1) -> dict[str, Any]:
    """Measure every model; write ``study.md``, ``study.json`` and ``study.png`` to ``out``.

    Per-model trials go to ``out/trials/<label>`` and resume like ``se3push trials``;
    accuracy figures are cached in ``out/accuracy/<label>.json``.
    """
    from planner.loop import push_scenario
    from se3net.checkpoint import manifest_hash, model_config
    from sim.datastore import read_manifest

    out = Path(out)
    dt = push_scenario(cfg.scenario).action.dt_control_s
    horizon, rollout = cfg.plan.optimiser.steps(dt), cfg.plan.rollout
    rows = []
    # the data by its contents: a folder made again under the same path is other data
    data_id = manifest_hash(read_manifest(cfg.data))
    models = parse_models(cfg.models)
    for _, model in models:  # a missing or cloudless model is refused before any trial runs
        if model not in BACKEND_MODELS:
            model_config(model)
    for label, model in models:
        safe = folder_name(label)
        cache = out / "accuracy" / f"{safe}.json"
        # the horizon error is the model rolled as the planner rolls it: a cache made with
        # other planner settings (one from before them: evaluation.records.BEFORE) is measured
        # again
        rolled = {"feedback": rollout.feedback, "contact_margin_m": rollout.contact_margin_m,
                  "horizon": horizon}  # fmt: skip
        # and the figures are of these weights on this data: a cache of others (or one from
        # before this was recorded, which cannot say) is measured again
        measured = {"data": data_id, "max_examples": cfg.max_examples,
                    "model_sha256": weights_of(model)}  # fmt: skip
        acc = json.loads(cache.read_text()) if cache.exists() else None
        if acc is not None:
            # a cache from before the horizon was recorded was rolled 4 steps
            was_rolled = {"horizon": round(BEFORE["optimiser"]["horizon_s"] / dt),
                          **acc.pop("rolled", BEFORE["rollout"])}  # fmt: skip
            if was_rolled != rolled or acc.pop("measured", None) != measured:
                acc = None
        if acc is None:
            acc = {
                **model_accuracy(model, cfg.data, max_examples=cfg.max_examples),
                **horizon_pose_error(
                    model,
                    cfg.data,
                    horizon,
                    max_windows=cfg.max_examples,
                    feedback=rollout.feedback,
                    contact_margin_m=rollout.contact_margin_m,
                ),  # fmt: skip
            }
            cache.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_json(cache, {**acc, "rolled": rolled, "measured": measured})
        trials = TrialsConfig(
            scenario=cfg.scenario, n=cfg.trials, model=model, seed=cfg.seed,
            max_steps=cfg.max_steps, plan=cfg.plan,
        )  # fmt: skip
        summary = run_trials(trials, out / "trials" / safe, workers=workers)
        summary.pop("config")
        rows.append({"label": label, "model": model, **acc, **summary})
    corr = rank_correlations(rows)
    learned = [r for r in rows if r["model"] not in BACKEND_MODELS]
    corr_learned = rank_correlations(learned)
    result = {
        "config": asdict(cfg),
        "rows": rows,
        "rank_correlation_with_success": corr,
        "rank_correlation_learned_only": corr_learned,
        "finding": finding(corr, len(rows), covered=measure_counts(rows))
        + " "
        + finding(
            corr_learned,
            len(learned),
            "learned models alone (no oracle, no-motion)",
            covered=measure_counts(learned),
        ),  # fmt: skip
    }
    atomic_write_json(out / "study.json", result)
    text = (
        table_markdown(rows) + f"\n{result['finding']}\n\nHorizon: {horizon} steps; "
        f"{cfg.trials} trials per model (seed {cfg.seed}, planner {cfg.plan.planner}); accuracy on "
        f"the test split of `{cfg.data}`.\n"
    )
    atomic_write_bytes(out / "study.md", text.encode())
    plot_study(rows, out / "study.png")
    return result
