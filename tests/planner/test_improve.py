import json

import numpy as np
import pytest
import torch

import planner.improve as improve_mod
from planner.improve import ImproveConfig, run_improve
from planner.trials import draw_trial
from se3net.checkpoint import read_checkpoint
from se3net.data import PushDataset
from se3net.train import TrainConfig, train
from sim import PushWorld
from sim.dataset import PLANNER_MODE, STEP_MODES
from sim.datastore import load_episodes, read_manifest


@pytest.fixture(scope="module")
def start_model(tiny_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("start")
    train(TrainConfig(data=str(tiny_data), out=str(out), iters=2, batch=4, eval_every=2,
                      val_examples=8, k=3), progress=False)  # fmt: skip
    return str(out / "best.pt")


def _cfg(tiny_data, start_model, **kw):
    base = dict(scenario="tiny", model=start_model, data=str(tiny_data), rounds=1,
                trials_per_round=2, heldout=2, max_steps=3, finetune_iters=2, eval_every=2,
                batch=4)  # fmt: skip
    return ImproveConfig(**{**base, **kw})


def test_a_round_adds_exact_planner_episodes_and_leaves_the_heldout_set_alone(
    tiny, tiny_data, start_model, tmp_path
):
    cfg = _cfg(tiny_data, start_model)
    result = run_improve(cfg, tmp_path / "imp")
    data = tmp_path / "imp" / "round_1" / "data"
    manifest = read_manifest(data)
    eps = load_episodes(data).arrays
    steps = int(eps["length"].sum())
    assert steps > 0 and manifest["stats"]["mode_steps"][PLANNER_MODE] == steps
    assert (eps["modes"][eps["modes"] >= 0] == STEP_MODES.index(PLANNER_MODE)).all()
    # exact associations: replaying the recorded actions in the world gives the recorded frames
    reset_seed = manifest["collection"][0]["reset_seed"]
    world = PushWorld(tiny)
    obs = world.reset(reset_seed)
    n = int(eps["length"][0])
    assert n > 0
    for t in range(n + 1):
        if t > 0:
            obs = world.step(eps["actions"][0, t - 1])
        assert (eps["part"][0, t] == obs.part).all()
        k = len(obs.T_world_part)
        assert np.abs(eps["T_world_part"][0, t, :k] - obs.T_world_part).max() < 1e-9
    # the pooled data has the new examples; the held-out trials are not among the collected
    pooled = PushDataset([tiny_data, data], split="train")
    alone = PushDataset(tiny_data, split="train")
    assert len(pooled) > len(alone)
    heldout = {draw_trial(tiny, 0, i)["reset_seed"] for i in range(cfg.heldout)}
    assert not heldout & {c["reset_seed"] for c in manifest["collection"]}
    lines = [
        [json.loads(x)["goal"] for x in (tmp_path / "imp" / f"round_{r}" / "heldout" /
                                         "trials.jsonl").read_text().splitlines()]
        for r in (0, 1)
    ]  # fmt: skip
    assert lines[0] == lines[1] and len(lines[0]) == cfg.heldout
    assert [r["round"] for r in result["rounds"]] == [0, 1]
    table = (tmp_path / "imp" / "improve.md").read_text()
    assert table.count("\n| ") == 2 and (tmp_path / "imp" / "improve.png").exists()


def test_an_interrupted_round_resumes_without_collecting_again(
    tiny_data, start_model, tmp_path, monkeypatch
):
    cfg = _cfg(tiny_data, start_model, trials_per_round=1)
    ref = run_improve(cfg, tmp_path / "ref")
    real_finetune, real_record = improve_mod.finetune, improve_mod.record_trial

    def interrupted(*args, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(improve_mod, "finetune", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_improve(cfg, tmp_path / "b")
    monkeypatch.setattr(improve_mod, "finetune", real_finetune)
    recorded = []
    monkeypatch.setattr(improve_mod, "record_trial",
                        lambda *a: recorded.append(a) or real_record(*a))  # fmt: skip
    again = run_improve(cfg, tmp_path / "b")
    assert recorded == []  # round 1's data was complete: not collected again
    a = read_checkpoint(tmp_path / "ref" / "round_1" / "model" / "best.pt")["state_dict"]
    b = read_checkpoint(tmp_path / "b" / "round_1" / "model" / "best.pt")["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    strip = ("median_replan_ms_median", "model")
    assert [{k: v for k, v in r.items() if k not in strip} for r in again["rounds"]] == [
        {k: v for k, v in r.items() if k not in strip} for r in ref["rounds"]
    ]
    with pytest.raises(ValueError, match="another improve run"):
        run_improve(_cfg(tiny_data, start_model, trials_per_round=1, action_noise=0.3),
                    tmp_path / "b")  # fmt: skip


@pytest.mark.scale
def test_ray_collects_the_same_bytes_as_the_local_pool(ray_local, tiny_data, tmp_path):
    from sim.jobs import Backend

    cfg = _cfg(tiny_data, "oracle")
    for name, jobs in (("local", Backend()), ("ray", Backend("ray", 2))):
        improve_mod.collect(cfg, "oracle", 1, tmp_path / name, jobs=jobs)
    a, b = (read_manifest(tmp_path / n)["shards"] for n in ("local", "ray"))
    assert a["shard_00000.npz"]["sha256"] == b["shard_00000.npz"]["sha256"]
    assert (tmp_path / "ray" / "shard_00000.npz").read_bytes() == (
        tmp_path / "local" / "shard_00000.npz"
    ).read_bytes()
