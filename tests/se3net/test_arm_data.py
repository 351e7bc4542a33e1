"""Arm data (joint-velocity controls) through the reader, training and evaluation: the control
dimension comes from the data, rollouts feed the recorded joint velocities, and a checkpoint
of arm data fits the arm scenario only."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

import se3net.train as train_mod
from scenarios import load_scenario
from se3net.checkpoint import CheckpointError, load_checkpoint, read_checkpoint
from se3net.data import PushDataset
from se3net.evaluate import evaluate
from se3net.rollout import pusher_controls
from se3net.train import TrainConfig, train
from sim.controls import JOINT_LAYOUT
from sim.dataset import DataConfig, generate
from sim.datastore import load_episodes


@pytest.fixture(scope="module")
def arm_data(tmp_path_factory):
    """21 arm episodes of 6 steps (train, val and test splits)."""
    root = tmp_path_factory.mktemp("arm_data")
    generate(DataConfig("arm", episodes=21, steps_per_episode=6, episodes_per_shard=7), root,
             progress=False)  # fmt: skip
    return root


def test_the_controls_of_arm_data_are_the_recorded_joint_velocities(arm_data):
    ds = PushDataset(arm_data, split="train", horizon=2)
    assert ds.control_layout == JOINT_LAYOUT.names and len(ds.control_layout) == 4
    b = ds.batch([0, 7, 11])
    eps = load_episodes(arm_data, "train").arrays
    e, t = ds.items[[0, 7, 11]].T
    recorded = np.stack([eps["actions"][e, t], eps["actions"][e, t + 1]], 1)
    assert b["u"].shape == (3, 2, 4) and b["state"].shape == (3, 0)
    np.testing.assert_allclose(b["u"].numpy(), recorded, rtol=1e-6)
    assert torch.equal(b["actions"], b["u"])
    assert torch.equal(pusher_controls(b["actions"], b["state"], 0.15), b["actions"])


def test_the_training_step_feeds_the_recorded_joint_velocities(arm_data):
    ds = PushDataset(arm_data, split="train", horizon=1)
    b = ds.batch([0, 5])
    seen = []

    class Spy:  # a network that moves nothing and records the controls it gets
        def encode(self, x, valid):
            return None

        def predict(self, x, u, valid, enc, masks=None, **sharpen):
            seen.append(u.clone())
            return SimpleNamespace(points=x, masks=None)

    train_mod.rollout_loss(Spy(), b, ds.scenario.action.dt_control_s)
    assert len(seen) == 1
    for h, u in enumerate(seen):
        assert torch.equal(u, b["u"][:, h])


def test_train_and_eval_on_arm_data_with_five_masks(arm_data, tmp_path):
    cfg = TrainConfig(data=str(arm_data), out=str(tmp_path / "run"), iters=4, batch=4,
                      eval_every=2, val_examples=8, k=5, stride=2)  # fmt: skip
    figures = train(cfg, progress=False)
    assert np.isfinite(figures["val_flow_mse_cm2"]) and figures["val_no_motion_cm2"] > 0
    blob = read_checkpoint(tmp_path / "run" / "best.pt")
    assert blob["control_layout"] == list(JOINT_LAYOUT.names)
    assert blob["model"]["control_dim"] == 4 and blob["model"]["k"] == 5
    (result,) = evaluate([tmp_path / "run" / "best.pt"], arm_data, tmp_path / "eval",
                         max_examples=16)  # fmt: skip
    assert result.no_motion_mse > 0 and np.isfinite(result.flow_mse)
    assert len(result.multi_step_mse) == 5 and np.all(np.isfinite(result.multi_step_mse))
    assert (tmp_path / "eval" / "run_examples.png").is_file()
    load_checkpoint(tmp_path / "run" / "best.pt", scenario=load_scenario("arm"))
    with pytest.raises(CheckpointError, match="takes controls .*yaw_vel_rad_s"):
        load_checkpoint(tmp_path / "run" / "best.pt", scenario=load_scenario("single_box"))
