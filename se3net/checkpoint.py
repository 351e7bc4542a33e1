"""Checkpoint files: weights plus everything needed to use them safely.

One file holds the model config, the weights (normalisation included), the scenario the data
came from (camera, action bounds, timing), the control layout, the data manifest's hash, the
code version, and for training checkpoints the optimiser and random states to resume exactly.
Loading one that does not fit the scenario or this code is refused, saying what differs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import pickle
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import torch

from scenarios import InputError, Scenario
from scenarios.config import differences, scenario_dict, scenario_fingerprint
from se3net.device import check_device
from se3net.model import ModelConfig, build_model
from se3net.pose_model import POSE_VARIANT, load_pose_model
from sim.controls import control_layout, layout_named
from sim.dataset import code_version
from sim.shards import atomic_write_bytes, sha256

CHECKPOINT_FORMAT = 1
DEFAULT_MODEL = Path(__file__).parent / "weights" / "default.pt"
"""the shipped se3net model (single_box)"""


class CheckpointError(InputError):
    """A checkpoint is missing, damaged, or does not fit the scenario or the code."""


def manifest_hash(manifest: dict[str, Any]) -> str:
    """Hash of a dataset's identity and shard checksums."""
    blob = json.dumps(
        {
            "identity": manifest["identity"],
            "shards": {k: v["sha256"] for k, v in manifest["shards"].items()},
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()


def save_checkpoint(
    path: str | Path,
    model: torch.nn.Module,
    *,
    scenario: Scenario,
    data_hash: str,
    extra: dict[str, Any] | None = None,
    train_state: dict[str, Any] | None = None,
) -> None:
    """Write a checkpoint atomically."""
    blob = {
        "format": CHECKPOINT_FORMAT,
        "code_version": code_version(),
        "model": model.cfg.to_dict(),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "scenario": scenario_dict(scenario),
        "fingerprint": scenario_fingerprint(scenario),
        "control_layout": list(control_layout(scenario).names),
        "data_hash": data_hash,
        "extra": extra or {},
    }
    if train_state is not None:
        blob["train_state"] = train_state
    buf = io.BytesIO()
    torch.save(blob, buf)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(Path(path), buf.getvalue())


def resolve_model(path: str | Path) -> Path:
    """The file of a checkpoint named by a path or by the name of a shipped model
    (``"default"``; any ``NAME`` with a ``se3net/weights/NAME.pt``)."""
    name = str(path)
    shipped = DEFAULT_MODEL.parent / f"{name}.pt"
    if "/" not in name and not name.endswith(".pt") and shipped.is_file():
        return shipped
    return Path(path)


def model_sha256(path: str | Path) -> str:
    """The SHA-256 of a checkpoint's file (``resolve_model``): which weights a result used."""
    file = resolve_model(path)
    if not file.is_file():
        raise CheckpointError(f"checkpoint {file} does not exist; train one with `se3push train`")
    return sha256(file)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The raw contents of a checkpoint file (a shipped model by name: ``resolve_model``),
    checked to be readable and of this format."""
    path = resolve_model(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist; train one with `se3push train`")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except (
        RuntimeError,
        EOFError,
        KeyError,
        zipfile.BadZipFile,
        pickle.UnpicklingError,
        ValueError,
    ) as err:
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        if isinstance(err, KeyError):  # the unpickler's, on a file torch.save did not write
            first = "it is not a file torch.save wrote"
        raise CheckpointError(
            f"checkpoint {path} cannot be read (not a checkpoint, truncated or damaged?): {first}"
        ) from None
    if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
        found = blob.get("format") if isinstance(blob, dict) else type(blob).__name__
        raise CheckpointError(
            f"checkpoint {path} has format {found!r}; this code reads format {CHECKPOINT_FORMAT}"
        )
    return blob


def refuse_trained_on(
    paths: Iterable[str | Path], manifest: dict[str, Any], data: str | Path
) -> None:
    """For a measurement on every episode of ``data`` (``--split all``, meant for a dataset
    held out from training; ``manifest`` is its manifest): refuse the first of the checkpoints
    trained on it, whose figures would be taken on its own training episodes.

    Raises:
        CheckpointError: a checkpoint's training data include ``data``.
    """
    held_out = manifest_hash(manifest)
    for path in paths:
        if held_out in str(read_checkpoint(path).get("data_hash", "")).split("+"):
            raise CheckpointError(
                f"--split all: {path} was trained on {data}, so all its episodes include the "
                "ones it learnt from; use --split test, or a dataset made to be held out"
            )


RETIRED_MODEL = {"controls": "fused", "valid_channel": False, "full_res_head": False,
                 "pivot": "centroid"}  # fmt: skip
"""network options tried and not kept (FiLM controls, a validity channel, a full-resolution
head, rotations about the camera origin), with the value of today's network: a checkpoint that
stored them so loads"""


def model_config(path: str | Path) -> ModelConfig:
    """The network configuration a checkpoint holds (say, to read its data at its stride)."""
    return _config_of(read_checkpoint(path), path)


def _config_of(blob: dict[str, Any], path: str | Path) -> ModelConfig:
    """A checkpoint's network configuration, or a CheckpointError naming the settings this
    code does not know (a checkpoint of another version of the code)."""
    stored = blob.get("model")
    if not isinstance(stored, dict):
        raise CheckpointError(f"checkpoint {path} holds no network configuration")
    if stored.get("variant") == POSE_VARIANT:
        raise CheckpointError(
            f"checkpoint {path} is a pose model: it plans (--model), but this command needs a "
            "cloud network (an SE3-Net or a flow net)"
        )
    retired = {k: v for k, v in stored.items() if k in RETIRED_MODEL}
    used = sorted(f"{k}={v}" for k, v in retired.items() if v != RETIRED_MODEL[k])
    if used:
        raise CheckpointError(
            f"checkpoint {path} uses network options retired from se3push ({', '.join(used)}, "
            "tried and not kept: docs/experiments); load it with the code of commit c7fec27"
        )
    stored = {k: v for k, v in stored.items() if k not in RETIRED_MODEL}
    known = {f.name for f in dataclasses.fields(ModelConfig)}
    unknown = sorted(set(stored) - known)
    if unknown:
        raise CheckpointError(
            f"checkpoint {path} has network settings this code does not know "
            f"({', '.join(unknown)}): it was written by another version of se3push"
        )
    try:
        return ModelConfig(**stored)
    except (TypeError, ValueError, InputError) as err:
        raise CheckpointError(f"checkpoint {path} holds a network configuration this code "
                              f"refuses: {err}") from None  # fmt: skip


def load_checkpoint(
    path: str | Path,
    *,
    scenario: Scenario | None = None,
    variant: str | None = None,
    device: str | torch.device = "cpu",
) -> tuple[torch.nn.Module, dict[str, Any]]:
    """Load a model for inference (in eval mode) and its checkpoint contents.

    Args:
        scenario: if given, the checkpoint must have been trained on data whose camera and
            action settings match it.
        variant: if given, the checkpoint must be of this variant.
        device: where the model goes (checked with ``se3net.device.check_device``).

    Raises:
        CheckpointError: missing, unreadable, or mismatched, with what differs.
        InputError: ``device`` does not exist on this machine.
    """
    device = check_device(device)
    blob = read_checkpoint(path)
    stored = blob.get("model")
    pose = isinstance(stored, dict) and stored.get("variant") == POSE_VARIANT
    cfg = None if pose else _config_of(blob, path)
    kind = POSE_VARIANT if pose else cfg.variant
    if variant is not None and kind != variant:
        raise CheckpointError(f"checkpoint {path} is a {kind!r} model, not {variant!r}")
    if layout_named(blob["control_layout"]) is None:
        raise CheckpointError(
            f"checkpoint {path} uses controls {blob['control_layout']}, which this code does "
            "not know"
        )
    if scenario is not None:
        ours = list(control_layout(scenario).names)
        if blob["control_layout"] != ours:
            raise CheckpointError(
                f"checkpoint {path} takes controls {blob['control_layout']}; scenario "
                f"{scenario.name!r} has {ours}"
            )
        theirs = f"scenario {scenario.name!r} has"
        diffs = differences(
            blob["fingerprint"], scenario_fingerprint(scenario), old_has="model has", new_has=theirs
        )
        if diffs:
            raise CheckpointError(
                f"checkpoint {path} does not fit scenario {scenario.name!r}: "
                + "; ".join(diffs[:4])
            )
        cam = scenario.camera
        seen = None if pose else (cfg.width * cfg.stride, cfg.height * cfg.stride)
        if not pose and seen != (cam.width, cam.height):  # a pose model has no pixels
            raise CheckpointError(
                f"checkpoint {path} is a {cfg.width}x{cfg.height} network at pixel stride "
                f"{cfg.stride} (images of {seen[0]}x{seen[1]}), which does not fit the "
                f"{cam.width}x{cam.height} camera of scenario {scenario.name!r}"
            )
        radius = stored.get("pusher_radius_m") if pose else None
        if radius is not None and radius != scenario.arm.pusher_radius_m:  # its gap features
            raise CheckpointError(
                f"checkpoint {path} is a pose model of a pusher of radius {radius} m; scenario "
                f"{scenario.name!r} has one of {scenario.arm.pusher_radius_m} m"
            )
    try:
        if pose:
            model = load_pose_model(blob)
        else:
            model = build_model(cfg)
            model.load_state_dict(blob["state_dict"])
    except (RuntimeError, TypeError) as err:
        raise CheckpointError(
            f"checkpoint {path} does not fit the {kind} network of this code: {err}"
        ) from None
    return model.to(device).eval(), blob
