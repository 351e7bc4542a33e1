"""Reading the dataset folders that ``sim.dataset`` writes: manifest, splits, episodes, stats.

Episodes are split into train/val/test by index (of every 20 episodes, 18 train, 1 val,
1 test), so no episode is ever in two splits, and an episode's split does not depend on how
many episodes the folder holds.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scenarios import Scenario, scenario_from_dict
from sim.camera import associated_targets
from sim.dataset import DATA_FORMAT, HIST_BIN_M, MANIFEST, NONZERO_FLOW_M
from sim.shards import DataError, read_shard

SPLITS = ("train", "val", "test")
"""the splits of every dataset by episode; ``"all"`` names every episode (a held-out dataset)"""
SPLIT_PERIOD = 20


def split_of(episode: int) -> str:
    """The split an episode belongs to (fixed by its index)."""
    r = episode % SPLIT_PERIOD
    return "test" if r == SPLIT_PERIOD - 1 else "val" if r == SPLIT_PERIOD - 2 else "train"


def read_manifest(root: str | Path) -> dict[str, Any]:
    """The manifest of a dataset folder, checked to be complete and of this code's format."""
    root = Path(root)
    path = root / MANIFEST
    if not path.is_file():
        raise DataError(
            f"{root} is not a dataset folder (no {MANIFEST}); make one with `se3push data`"
        )
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DataError(f"{path} is corrupted ({err}); regenerate the dataset") from None
    identity = manifest.get("identity") if isinstance(manifest, dict) else None
    if not isinstance(identity, dict) or "format" not in identity:
        raise DataError(
            f"{path} is not a dataset manifest (no identity and format); point to a folder made "
            "with `se3push data`"
        )
    fmt = identity["format"]
    if fmt != DATA_FORMAT:
        raise DataError(f"{root} holds data format {fmt}; this code reads format {DATA_FORMAT}")
    if not manifest.get("complete"):
        raise DataError(
            f"{root} is incomplete (an interrupted `se3push data` run); run the same command "
            "again to finish it"
        )
    return manifest


def scenario_of(manifest: dict[str, Any]) -> Scenario:
    """The scenario a dataset was generated with (from its stored parameters)."""
    return scenario_from_dict(manifest["identity"]["scenario"], where="the dataset's manifest")


@dataclass
class Episodes:
    """All episodes of a split, stacked (leading axis: episode)."""

    arrays: dict[str, np.ndarray]
    index: np.ndarray
    """global episode index of each row"""


def load_episodes(root: str | Path, split: str = "all", *, verify: bool = True) -> Episodes:
    """Read the shards of a dataset (checksums verified) and keep one split's episodes
    (``"all"``: every episode)."""
    if split not in (*SPLITS, "all"):
        raise ValueError(f"unknown split {split!r}; known: {', '.join(SPLITS)}, all")
    root = Path(root)
    manifest = read_manifest(root)
    chunks: dict[str, list[np.ndarray]] = {}
    for name in sorted(manifest["shards"]):
        shard = read_shard(
            root / name, expected_sha256=manifest["shards"][name]["sha256"] if verify else None
        )
        keep = np.array(
            [split == "all" or split_of(int(e)) == split for e in shard["episode_index"]]
        )
        for k, v in shard.items():
            chunks.setdefault(k, []).append(v[keep])
    arrays = {k: np.concatenate(v) for k, v in chunks.items()}
    return Episodes(arrays=arrays, index=arrays["episode_index"])


def frame_cloud(
    arrays: dict[str, np.ndarray], e: int, t: int, T_cam_world: np.ndarray, *, at: int | None = None
) -> np.ndarray:
    """Frame t's points (3,H,W) of episode row e, placed with the parts' poses at frame
    ``at`` (default t): the observed cloud, or its exact targets after ``at - t`` steps."""
    return associated_targets(
        arrays["points_part"][e, t].astype(np.float64),
        arrays["part"][e, t],
        arrays["T_world_part"][e, t if at is None else at],
        T_cam_world,
    )


def summarize(manifest: dict[str, Any]) -> dict[str, Any]:
    """Headline statistics of a dataset from its manifest (one-step flow over every point
    whose true flow is non-zero, seen by the camera or not; ``se3push eval`` measures the
    seen ones, so its no-motion figure differs a little from ``no_motion_mse_cm2``)."""
    st = manifest["stats"]
    n = max(st["moving_points"], 1)
    hist = np.asarray(st["flow_hist"], float)
    cdf = np.cumsum(hist) / max(hist.sum(), 1)
    p95 = (np.searchsorted(cdf, 0.95) + 1) * HIST_BIN_M
    steps = sum(st["mode_steps"].values())
    return {
        "episodes": st["episodes"],
        "examples": st["examples"],
        "object_motion_fraction": st["moved_examples"] / max(st["examples"], 1),
        "moving_points_per_example": st["moving_points"] / max(st["examples"], 1),
        "mean_flow_m": st["flow_sum_m"] / n,
        "p95_flow_m": float(p95),
        "no_motion_mse_cm2": st["flow_sq_sum_m2"] / n * 1e4,
        "mode_fractions": {m: k / max(steps, 1) for m, k in st["mode_steps"].items()},
        "qp_failures": st["qp_failures"],
        "moving_threshold_m": NONZERO_FLOW_M,
    }
