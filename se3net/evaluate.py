"""Evaluation like the paper's Table 1, plus what the paper only showed as pictures.

For each checkpoint, on the test split (or every episode of a held-out dataset): one-step
flow MSE (cm^2) beside the no-motion baseline's and its ratio; mask binariness and IoU with
the true parts (SE3-Net variants); multi-step error when predictions are fed back as input for
1..5 steps. Results come back as data; ``table_markdown`` and ``save_pictures`` turn them
into a table and PNGs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from scenarios import InputError
from se3net.checkpoint import DEFAULT_MODEL, load_checkpoint, model_config, refuse_trained_on
from se3net.data import PushDataset, evenly_spaced, paper_noise, subsample_batch
from se3net.metrics import FlowStats, MaskStats, true_flow
from se3net.rollout import check_feedback, reprojection, rollout
from sim.folders import writes_folder
from sim.shards import atomic_write_bytes, portable_path

MULTI_STEPS = 5
EVAL_NOISE_SEED = 12345
"""seed of the test data's noise (``--noise``), apart from any training seed"""


@dataclass
class EvalResult:
    """Figures of one checkpoint on one dataset's test split (or all of it)."""

    name: str
    variant: str
    checkpoint: str
    """the checkpoint's path, relative to the current directory if under it"""
    split: str
    """the dataset's episodes used: ``test``, or ``all`` for a held-out dataset"""
    examples: int
    flow_mse: float
    """one-step flow MSE over moving points, cm^2"""
    no_motion_mse: float
    ratio_to_no_motion: float
    mask_binariness: float | None
    iou: float | None
    multi_step_mse: list[float] = field(default_factory=list)
    """flow MSE (cm^2) after 1..5 fed-back steps"""
    multi_step_no_motion: list[float] = field(default_factory=list)
    noise: str = "none"
    """the paper's robustness noise on the test data (``se3net.data.PAPER_NOISE``)"""
    feedback: str = "grid"
    """how the fed-back steps feed predictions back (``se3net.rollout``): on the observed
    ``grid`` or ``rendered`` again by the camera"""
    stride: int = 1
    """the model reads every ``stride``-th pixel: the points its figures (and the no-motion
    baseline beside them) are taken over"""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def checkpoint_name(path: str | Path) -> str:
    """``default`` for the shipped model, else the run folder's name (or the file's stem)."""
    path = Path(path)
    if path.resolve() == DEFAULT_MODEL.resolve():
        return "default"
    return path.parent.name if path.stem in ("best", "last") else path.stem


def checkpoint_names(paths: list[str | Path]) -> list[str]:
    """Names that tell the checkpoints apart: ``checkpoint_name``, with more of the path in
    front where two would share one (``round_1/model`` and ``round_3/model`` for their
    ``best.pt``; ``c1/model`` and ``c2/model`` for two ``model.pt``).

    Raises:
        InputError: one checkpoint given twice (no name tells it apart from itself).
    """
    names = [checkpoint_name(p) for p in paths]
    for depth in range(1, 8):
        clash = {n for n in names if names.count(n) > 1}
        if not clash:
            return names
        for i, path in enumerate(paths):
            if names[i] in clash:
                path = Path(path).resolve()
                # a best.pt or last.pt is named by its folder already: more starts above it
                above = path.parent.parent if path.stem in ("best", "last") else path.parent
                names[i] = "/".join([*above.parts[len(above.parts) - depth :],
                                     checkpoint_name(path)])  # fmt: skip
    twice = sorted({str(p) for p in paths if [str(q) for q in paths].count(str(p)) > 1})
    raise InputError(
        f"checkpoint {twice[0] if twice else names[0]} is given twice; give each checkpoint once"
    )


@torch.no_grad()
def evaluate_checkpoint(
    path: str | Path,
    data: str | Path,
    *,
    max_examples: int = 2000,
    batch: int = 64,
    device: str = "cpu",
    name: str | None = None,
    split: str = "test",
    noise: str = "none",
    feedback: str = "grid",
) -> EvalResult:
    """Evaluate one checkpoint on the test split of ``data`` (``split="all"``: on every
    episode, for a dataset made to be held out; ``name``: its label, by default
    ``checkpoint_name``; ``noise``: the test data under one of the paper's noises, drawn with
    seed ``EVAL_NOISE_SEED``; ``feedback``: how the fed-back steps feed predictions back,
    ``grid`` or ``rendered``)."""
    check_feedback(feedback)
    stride = model_config(path).stride
    reading = {"stride": stride, "noise": paper_noise(noise), "seed": EVAL_NOISE_SEED,
               "device": device}  # fmt: skip
    one = PushDataset(data, split=split, horizon=1, **reading)
    if split == "all":
        refuse_trained_on([path], one.manifest, data)
    model, blob = load_checkpoint(path, scenario=one.scenario, device=device)
    flow, masks = FlowStats(), MaskStats()
    idx = evenly_spaced(len(one), max_examples)
    for s in range(0, len(idx), batch):
        b = {k: v.to(device) for k, v in one.batch(idx[s : s + batch]).items()}
        pred = model(b["points"], b["u"][:, 0], b["valid"])
        truth = true_flow(b, 0)
        flow.add(pred.points, b["points"], b["target"][:, 0], b["target_valid"][:, 0], truth)
        if pred.masks is not None:
            masks.add(pred.masks, b["part"], b["points"], b["target"][:, 0], truth)
    multi = PushDataset(data, split=split, horizon=MULTI_STEPS, **reading)
    dt = multi.scenario.action.dt_control_s
    reproject = reprojection(feedback, multi.scenario.camera, stride)
    steps = [FlowStats() for _ in range(MULTI_STEPS)]
    idx = evenly_spaced(len(multi), max_examples // 2)
    for s in range(0, len(idx), batch):
        b = {k: v.to(device) for k, v in multi.batch(idx[s : s + batch]).items()}
        # the recorded commands; the pusher positions (if the controls hold them) integrated
        clouds = rollout(
            model, b["points"], b["valid"], b["actions"], b["state"], dt, reproject=reproject
        )
        for k, x in enumerate(clouds):
            steps[k].add(x, b["points"], b["target"][:, k], b["target_valid"][:, k],
                         true_flow(b, k))  # fmt: skip
    is_se3 = masks.n_points > 0
    return EvalResult(
        name=name or checkpoint_name(path),
        variant=blob["model"]["variant"],
        checkpoint=portable_path(path),
        split=split,
        examples=len(evenly_spaced(len(one), max_examples)),
        flow_mse=flow.mse_cm2,
        no_motion_mse=flow.no_motion_cm2,
        ratio_to_no_motion=flow.ratio,
        mask_binariness=masks.binariness if is_se3 else None,
        iou=masks.iou if is_se3 else None,
        multi_step_mse=[s.mse_cm2 for s in steps],
        multi_step_no_motion=[s.no_motion_cm2 for s in steps],
        noise=noise,
        feedback=feedback,
        stride=stride,
    )


def table_markdown(results: list[EvalResult], data: str) -> str:
    """A Markdown table laid out like the paper's Table 1 (one column per model + no-motion)."""

    def fmt(x: float | None, digits: int = 3) -> str:
        return "–" if x is None else f"{x:.{digits}f}"

    head = "| | " + " | ".join(f"{r.name} ({r.variant})" for r in results) + " | no-motion |"
    rule = "|---" * (len(results) + 2) + "|"
    # the no-motion baseline once per point sampling: models of other strides score other points
    by_stride = {r.stride: r for r in reversed(results)}
    strides = list(dict.fromkeys(r.stride for r in results))

    def no_motion(figure: Callable[[EvalResult], float]) -> str:
        cells = [f"{figure(by_stride[k]):.3f}" for k in strides]
        return " / ".join(cells) if cells else "nan"

    rows = [
        "| flow MSE (cm²), 1 step | "
        + " | ".join(fmt(r.flow_mse) for r in results)
        + f" | {no_motion(lambda r: r.no_motion_mse)} |",
        "| ratio to no-motion | "
        + " | ".join(fmt(r.ratio_to_no_motion) for r in results)
        + " | 1 |",
        "| mask binariness (moving bodies) | "
        + " | ".join(fmt(r.mask_binariness) for r in results)
        + " | – |",
        "| IoU with true parts (moving bodies) | "
        + " | ".join(fmt(r.iou) for r in results)
        + " | – |",
    ]
    for k in range(MULTI_STEPS):
        nmk = no_motion(lambda r, k=k: r.multi_step_no_motion[k])
        rows.append(
            f"| flow MSE (cm²), {k + 1} steps fed back | "
            + " | ".join(fmt(r.multi_step_mse[k]) for r in results)
            + f" | {nmk} |"
        )
    n = results[0].examples if results else 0
    which = "All episodes" if results and results[0].split == "all" else "Test split"
    noisy = f" under `{results[0].noise}` noise" if results and results[0].noise != "none" else ""
    fed = results[0].feedback if results else "grid"
    fed = "rendered again by the camera" if fed == "rendered" else "on the observed pixel grid"
    note = (
        f"\n{which} of `{data}`{noisy}, {n} one-step examples; flow MSE averages the squared "
        "error over points whose true flow is non-zero (> 0.1 mm) and that stay visible. "
        f"Fed-back rows: each prediction fed back {fed}.\n"
    )
    if len(strides) > 1:
        note += (
            "The models read every k-th pixel for different k "
            f"({', '.join(str(k) for k in strides)}), so each scores other points; the "
            "no-motion column gives one figure per k, in that order.\n"
        )
    return "\n".join([head, rule, *rows]) + "\n" + note


@torch.no_grad()
def save_pictures(
    paths: list[str | Path],
    data: str | Path,
    out_dir: str | Path,
    *,
    n: int = 3,
    names: list[str] | None = None,
    split: str = "test",
) -> list[Path]:
    """For each checkpoint, a PNG of a few examples of ``split`` where an object moves: true
    parts, mask argmax (SE3-Nets), true and predicted flow magnitude, and the error."""
    from sim.render import pyplot, save_figure

    ds = PushDataset(data, split=split, horizon=1)
    scan = evenly_spaced(len(ds), 400)
    sb = ds.batch(scan)
    obj_flow = (
        ((sb["target"][:, 0] - sb["points"]).norm(dim=1) * (sb["part"] >= 2)).flatten(1).amax(1)
    )
    picks = scan[
        torch.argsort(obj_flow, descending=True)[:n].numpy()
    ].tolist()  # most object motion
    full = ds.batch(picks)
    written = []
    plt = pyplot()
    for path, name in zip(paths, names or checkpoint_names(paths), strict=True):
        model, blob = load_checkpoint(path, scenario=ds.scenario)
        b = subsample_batch(full, model.cfg.stride)
        pred = model(b["points"], b["u"][:, 0], b["valid"])
        fig, axes = plt.subplots(len(picks), 5, figsize=(17, 3.4 * len(picks)), squeeze=False)
        true_f = (b["target"][:, 0] - b["points"]).norm(dim=1) * 1e3
        pred_f = (pred.points - b["points"]).norm(dim=1) * 1e3
        err = (pred.points - b["target"][:, 0]).norm(dim=1) * 1e3
        for r in range(len(picks)):
            valid = b["valid"][r].numpy()
            vmax = float(true_f[r].max())
            panels = [
                (b["part"][r].numpy() + 1.0, "true parts", "tab10", 0, 9),
                (
                    (pred.masks[r].argmax(0).numpy() + 1.0) if pred.masks is not None else None,
                    "mask argmax",
                    "tab10",
                    0,
                    9,
                ),
                (true_f[r].numpy(), "true |flow| (mm)", "magma", 0, vmax),
                (pred_f[r].numpy(), "predicted |flow| (mm)", "magma", 0, vmax),
                (err[r].numpy(), "|error| (mm)", "magma", 0, vmax),
            ]
            for ax, (img, title, cmap, lo, hi) in zip(axes[r], panels, strict=True):
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(title)
                if img is None:
                    ax.set_axis_off()
                    continue
                im = ax.imshow(np.where(valid, img, np.nan), cmap=cmap, vmin=lo, vmax=hi)
                if cmap == "magma":
                    fig.colorbar(im, ax=ax)
        fig.suptitle(f"{name} ({blob['model']['variant']}): {split} examples")
        out = Path(out_dir) / f"{name.replace('/', '_')}_examples.png"
        save_figure(fig, out)
        written.append(out)
    return written


@writes_folder(lambda a: a.arguments["out_dir"])
def evaluate(
    paths: list[str | Path],
    data: str | Path,
    out_dir: str | Path,
    *,
    max_examples: int = 2000,
    split: str = "test",
    noise: str = "none",
    device: str = "cpu",
    feedback: str = "grid",
) -> list[EvalResult]:
    """Evaluate checkpoints on the test split of ``data`` (``split="all"``: every episode;
    ``noise``: under one of the paper's noises); write ``table.md``, ``eval.json`` and PNGs to
    ``out_dir``. Paths under the current directory are recorded relative to it."""
    import json

    if max_examples < 2:
        raise InputError(
            f"--max-examples must be at least 2 (half of them score the fed-back steps), got "
            f"{max_examples}"
        )
    out_dir = Path(out_dir)
    names = checkpoint_names(paths)
    if split == "all":  # every checkpoint before any is measured
        from sim.datastore import read_manifest

        refuse_trained_on(paths, read_manifest(data), data)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = [
        evaluate_checkpoint(
            p,
            data,
            max_examples=max_examples,
            name=name,
            split=split,
            noise=noise,
            device=device,
            feedback=feedback,
        )  # fmt: skip
        for p, name in zip(paths, names, strict=True)
    ]
    atomic_write_bytes(out_dir / "table.md", table_markdown(results, portable_path(data)).encode())
    eval_json = json.dumps({r.name: r.to_dict() for r in results}, indent=1) + "\n"
    atomic_write_bytes(out_dir / "eval.json", eval_json.encode())
    save_pictures(paths, data, out_dir, names=names, split=split)
    return results
