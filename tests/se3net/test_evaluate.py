import json

import pytest

from se3net.data import PushDataset
from se3net.evaluate import evaluate
from se3net.train import TrainConfig, train


@pytest.fixture(scope="module")
def work(tiny_data, tmp_path_factory):
    """A folder holding ``runs/tiny/best.pt``, a tiny model trained on ``tiny_data``."""
    work = tmp_path_factory.mktemp("work")
    cfg = TrainConfig(data=str(tiny_data), out=str(work / "runs" / "tiny"), iters=4, batch=4,
                      eval_every=2, val_examples=8, k=3)  # fmt: skip
    train(cfg, progress=False)
    return work


def test_eval_records_a_checkpoint_under_the_cwd_relative_to_it(work, tiny_data, monkeypatch):
    monkeypatch.chdir(work)
    absolute = work / "runs" / "tiny" / "best.pt"
    (result,) = evaluate([absolute], tiny_data, "eval", max_examples=8)
    assert result.checkpoint == "runs/tiny/best.pt"
    figures = json.loads((work / "eval" / "eval.json").read_text())
    assert figures["tiny"]["checkpoint"] == "runs/tiny/best.pt"
    assert str(work) not in (work / "eval" / "eval.json").read_text()


@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """Tiny data of another seed, which the tiny model never saw."""
    from sim.dataset import DataConfig, generate

    root = tmp_path_factory.mktemp("held_out")
    generate(DataConfig("tiny", episodes=21, steps_per_episode=8, episodes_per_shard=7, seed=1),
             root, progress=False)  # fmt: skip
    return root


def test_eval_on_all_episodes_uses_every_episode(work, tiny_data, held_out, tmp_path):
    best = work / "runs" / "tiny" / "best.pt"
    (test,) = evaluate([best], held_out, tmp_path / "test", max_examples=10_000)
    (every,) = evaluate([best], held_out, tmp_path / "all", max_examples=10_000, split="all")
    assert (test.split, every.split) == ("test", "all")
    assert test.examples == len(PushDataset(held_out, split="test"))
    assert every.examples == len(PushDataset(held_out, split="all")) > 10 * test.examples
    assert "All episodes of" in (tmp_path / "all" / "table.md").read_text()
    assert "Test split of" in (tmp_path / "test" / "table.md").read_text()


def test_evaluations_fed_back_rows_are_the_planners_rollout(work, tiny_data):
    """The 'N steps fed back' flow MSE of eval equals the one computed from the clouds the
    planner's backend predicts for the same examples (pusher integrated from the commands)."""
    import torch

    from planner.dynamics import PlanState
    from planner.learned import LearnedDynamics
    from se3net.checkpoint import load_checkpoint
    from se3net.data import evenly_spaced
    from se3net.evaluate import MULTI_STEPS, evaluate_checkpoint
    from se3net.metrics import FlowStats

    best = work / "runs" / "tiny" / "best.pt"
    n = 6
    result = evaluate_checkpoint(best, tiny_data, max_examples=2 * n)
    ds = PushDataset(tiny_data, split="test", horizon=MULTI_STEPS)
    model, _ = load_checkpoint(best, scenario=ds.scenario)
    dyn = LearnedDynamics(model, ds.scenario, name="se3net")
    b = ds.batch(evenly_spaced(len(ds), n))
    steps = [FlowStats() for _ in range(MULTI_STEPS)]
    T = torch.from_numpy(ds.camera.T_world_cam).float()
    with torch.no_grad():
        for j in range(len(b["points"])):
            state = PlanState(b["points"][j], b["valid"][j], b["part"][j] == 2, torch.zeros(3),
                              b["u"][j, 0, 2:], T, footprint_radius_m=0.05,
                              yaw_period_rad=None)  # fmt: skip
            clouds = dyn.rollout(state, b["u"][j : j + 1, :, :2], clouds=True).clouds[0]
            for k in range(MULTI_STEPS):
                steps[k].add(clouds[k][None], b["points"][j : j + 1], b["target"][j : j + 1, k],
                             b["target_valid"][j : j + 1, k])  # fmt: skip
    for k in range(MULTI_STEPS):
        assert result.multi_step_mse[k] == pytest.approx(steps[k].mse_cm2, rel=1e-4)


def test_eval_refuses_too_few_examples_to_score_before_writing_anything(work, tiny_data, tmp_path):
    """With under 2 examples the fed-back rows would score none (0.000, a perfect score to
    the eye): refused in one line, exit 2, and no folder is made."""
    from se3push.cli import main

    best = str(work / "runs" / "tiny" / "best.pt")
    for n in ("0", "1", "-1"):
        out = tmp_path / f"n{n}"
        assert main(["eval", "--checkpoints", best, "--data", str(tiny_data),
                     "--max-examples", n, "--out", str(out)]) == 2  # fmt: skip
        assert not out.exists()


def test_the_no_motion_column_has_a_figure_for_each_models_points(work, tiny_data, tmp_path):
    """Models that read every 2nd pixel score other points than those reading every pixel, so
    the baseline they are compared with differs; the table gives both, not the first model's."""
    cfg = TrainConfig(data=str(tiny_data), out=str(tmp_path / "s2"), iters=2, batch=4,
                      eval_every=2, val_examples=8, k=3, stride=2)  # fmt: skip
    train(cfg, progress=False)
    paths = [work / "runs" / "tiny" / "best.pt", tmp_path / "s2" / "best.pt"]
    every, second = evaluate(paths, tiny_data, tmp_path / "eval", max_examples=8)
    assert (every.stride, second.stride) == (1, 2)
    assert every.no_motion_mse != second.no_motion_mse
    table = (tmp_path / "eval" / "table.md").read_text()
    one_step = next(ln for ln in table.splitlines() if ln.startswith("| flow MSE (cm²), 1 step"))
    assert one_step.endswith(f"| {every.no_motion_mse:.3f} / {second.no_motion_mse:.3f} |")
    assert "(1, 2)" in table


def test_eval_on_all_episodes_refuses_a_model_trained_on_them(work, tiny_data, tmp_path):
    """Every episode of the model's own training data would score it on what it learnt from."""
    from se3net.checkpoint import CheckpointError

    best = work / "runs" / "tiny" / "best.pt"
    with pytest.raises(CheckpointError, match="was trained on"):
        evaluate([best], tiny_data, tmp_path / "eval", max_examples=8, split="all")
    assert not (tmp_path / "eval").exists()  # refused before anything was measured or made
