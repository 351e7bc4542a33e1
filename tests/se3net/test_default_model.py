"""The shipped models: they load for single_box and predict unseen pushes well; the default
loads for every packaged scenario of the same camera and actions."""

from pathlib import Path

import pytest
import torch

from scenarios import list_scenarios, load_scenario
from se3net.checkpoint import DEFAULT_MODEL, CheckpointError, load_checkpoint, resolve_model
from se3net.data import PushDataset
from se3net.metrics import FlowStats, MaskStats
from sim.dataset import DataConfig, generate


@pytest.fixture(scope="module")
def unseen(tmp_path_factory):
    root = tmp_path_factory.mktemp("unseen")
    generate(
        DataConfig("single_box", episodes=3, seed=123, episodes_per_shard=3), root, progress=False
    )
    return root


# measured on these 60 examples (ratio to no-motion, mask binariness); each threshold leaves
# about a quarter of the measured value (of the non-binary share for binariness)
SHIPPED = {
    "default": (0.047, 0.996, 0.059, 0.995),  # the generalist: 32x32, k = 6, household + single_box
    "single_box": (0.063, 0.989, 0.079, 0.986),  # the 32x32 single_box specialist it replaced
    "single_box_64": (0.035, 0.988, 0.044, 0.985),  # the 64x64 model that one replaced
}


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_models_fit_single_box_and_beat_no_motion_on_unseen_episodes(unseen, name):
    model, blob = load_checkpoint(name, scenario=load_scenario("single_box"), variant="se3net")
    assert resolve_model(name).stat().st_size < 8e6
    ds = PushDataset(unseen, split="train", stride=model.cfg.stride)  # seed 123: never seen
    b = ds.batch(range(len(ds)))
    with torch.no_grad():
        pred = model(b["points"], b["u"][:, 0], b["valid"])
    flow, masks = FlowStats(), MaskStats()
    flow.add(pred.points, b["points"], b["target"][:, 0], b["target_valid"][:, 0])
    masks.add(pred.masks, b["part"], b["points"], b["target"][:, 0])
    *_, max_ratio, min_binariness = SHIPPED[name]
    assert flow.ratio < max_ratio
    assert masks.binariness > min_binariness


def test_the_default_name_resolves_to_the_shipped_file():
    assert resolve_model("default") == DEFAULT_MODEL
    by_name, by_path = load_checkpoint("default")[1], load_checkpoint(DEFAULT_MODEL)[1]
    assert by_name["data_hash"] == by_path["data_hash"]
    assert resolve_model("runs/x/default") == Path("runs/x/default")  # a path stays a path


@pytest.mark.parametrize("name", sorted(list_scenarios()))
def test_the_default_fits_every_packaged_scenario_of_the_table_top_camera(name):
    """Issue 16: one default for single_box, multi_object, household and the held-out objects;
    the arm (joint-velocity controls) and tiny (a 32x32 camera) are refused with a reason."""
    scenario = load_scenario(name)
    if name in ("arm", "tiny"):
        refused = f"(takes controls|does not fit scenario '{name}')"
        with pytest.raises(CheckpointError, match=refused):
            load_checkpoint("default", scenario=scenario)
    else:
        model, _ = load_checkpoint("default", scenario=scenario)
        assert model.cfg.k == 6
