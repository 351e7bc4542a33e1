"""``se3push train``: an SE3-Net or a baseline (``se3net.train``, also under ``torchrun``), or a
pose-space model (``--variant pose``: ``se3net.pose_model``)."""

from __future__ import annotations

import argparse
import sys

from scenarios import InputError
from se3push.options import noise_option

CLOUD_ONLY = ("k", "stride", "init", "later_fraction", "later_from", "noise", "keep_every",
              "resume", "device", "eval_every")  # fmt: skip
"""the flags of a cloud network's training, refused for ``--variant pose`` unless left at their
defaults"""


def _cmd_train_pose(args: argparse.Namespace) -> int:
    """``train --variant pose``: a pose-space model (``se3net.pose_model``)."""
    from se3net.pose_model import train_pose_model
    from se3net.train import TrainingDiverged

    given = [f"--{d.replace('_', '-')}" for d in CLOUD_ONLY
             if getattr(args, d) != args.cloud_defaults[d]]  # fmt: skip
    if given:
        raise InputError(f"{', '.join(given)}: not for --variant pose (a pose model trains in "
                         "a few minutes on the CPU, from scratch); leave them out")  # fmt: skip
    try:
        m = train_pose_model(list(args.data), args.out, iters=args.iters,
                             batch=256 if args.batch is None else args.batch,
                             lr=args.lr, seed=args.seed)  # fmt: skip
    except TrainingDiverged as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(f"done: {args.out}/best.pt; validation position error after 1 and 8 steps "
          f"{m['first_mm']:.2f} and {m['last_mm']:.2f} mm (no motion: {m['still_first_mm']:.2f} "
          f"and {m['still_last_mm']:.2f} mm)")  # fmt: skip
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from se3net.distributed import end_process, ranks_from_env
    from se3net.train import TrainConfig, TrainingDiverged, train

    if args.variant == "pose":
        return _cmd_train_pose(args)
    data = args.data[0] if len(args.data) == 1 else tuple(args.data)
    cfg = TrainConfig(
        data=data, out=args.out, variant=args.variant, iters=args.iters,
        batch=32 if args.batch is None else args.batch,
        lr=args.lr, seed=args.seed, device=args.device, k=args.k,
        eval_every=args.eval_every, keep_every=args.keep_every,
        init=args.init, later_fraction=args.later_fraction, later_from=args.later_from,
        stride=args.stride, noise=args.noise,
    )  # fmt: skip
    ranks, code = ranks_from_env(), 0
    try:
        figures = train(cfg, resume=args.resume)
    except TrainingDiverged as err:
        print(f"error: {err}", file=sys.stderr)
        code = 1
    else:
        if ranks.main:  # under torchrun, rank 0 speaks for the run
            print(
                f"done: {args.out}/best.pt; last validation flow MSE "
                f"{figures['val_flow_mse_cm2']:.4f} cm^2, ratio to no-motion "
                f"{figures['val_ratio']:.3f}"
            )
    if ranks.world > 1:
        end_process(code)  # not through the interpreter's exit (its docstring says why)
    return code


def add_train_parser(sub: argparse._SubParsersAction) -> None:
    """The ``train`` command's parser, under ``sub``."""
    s = sub.add_parser("train", help="train an SE3-Net or a baseline on a dataset")
    s.add_argument(
        "--data",
        required=True,
        nargs="+",
        help="dataset folder(s) (from `se3push data` or `se3push improve`), pooled",
    )
    s.add_argument(
        "--variant", default="se3net",
        help="se3net, se3net-large, no-penalty, flow, flow-large, or pose (a pose-space model)",
    )  # fmt: skip
    s.add_argument("--out", required=True, help="run folder (checkpoints, metrics.jsonl)")
    s.add_argument("--iters", type=int, default=6000)
    s.add_argument("--batch", type=int, default=None, help="examples a step (32; pose: 256)")
    s.add_argument("--lr", type=float, default=1e-3)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or mps")
    s.add_argument("--k", type=int, default=4, help="number of masks (SE3-Net variants)")
    s.add_argument("--eval-every", type=int, default=250, help="iterations between validations")
    s.add_argument("--keep-every", type=int, default=0, help="keep a checkpoint every N iterations")
    s.add_argument("--init", default=None, help="start from this checkpoint's weights (fine-tune)")
    s.add_argument(
        "--later-fraction",
        type=float,
        default=0.0,
        help="share of each batch drawn from the later --data folders (0: uniform)",
    )
    s.add_argument(
        "--later-from",
        type=int,
        default=1,
        help="the later --data folders start at this index (1: the second; 2 when two "
        "exploration folders come first)",
    )
    s.add_argument(
        "--stride",
        type=int,
        default=1,
        help="the network sees every N-th pixel of the camera's image in each direction "
        "(2: a 32x32 planning-resolution model of 64x64 data, about 3x faster to plan with)",
    )
    noise_option(s, "train and validate under the paper's robustness noise (Table 2)")
    s.add_argument("--resume", action="store_true", help="continue the run in --out exactly")
    s.set_defaults(run=_cmd_train, cloud_defaults={d: s.get_default(d) for d in CLOUD_ONLY})
