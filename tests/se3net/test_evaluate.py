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


def test_eval_on_all_episodes_uses_every_episode(work, tiny_data, tmp_path):
    best = work / "runs" / "tiny" / "best.pt"
    (test,) = evaluate([best], tiny_data, tmp_path / "test", max_examples=10_000)
    (every,) = evaluate([best], tiny_data, tmp_path / "all", max_examples=10_000, split="all")
    assert (test.split, every.split) == ("test", "all")
    assert test.examples == len(PushDataset(tiny_data, split="test"))
    assert every.examples == len(PushDataset(tiny_data, split="all")) > 10 * test.examples
    assert "All episodes of" in (tmp_path / "all" / "table.md").read_text()
    assert "Test split of" in (tmp_path / "test" / "table.md").read_text()
