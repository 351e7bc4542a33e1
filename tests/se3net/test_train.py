import dataclasses
import json

import numpy as np
import pytest
import torch

import se3net.train as train_mod
from scenarios import InputError, load_scenario
from se3net.checkpoint import CheckpointError, load_checkpoint, model_config, read_checkpoint
from se3net.data import PushDataset
from se3net.evaluate import evaluate
from se3net.metrics import point_loss
from se3net.model import ModelConfig, build_model
from se3net.train import TrainConfig, TrainingDiverged, fit_normalisation, train
from sim.shards import DataError
from tests.conftest import with_fields


def test_tiny_se3net_overfits_a_handful_of_examples(tiny_data):
    torch.manual_seed(0)
    ds = PushDataset(tiny_data, split="train")
    moving = [
        i
        for i in range(len(ds))
        if (ds[i]["target"][0] - ds[i]["points"]).norm(dim=0)[ds[i]["part"] >= 2].max() > 2e-3
    ]
    b = ds.batch(moving[:4] + list(range(4)))
    model = build_model(ModelConfig(height=32, width=32, k=4))
    fit_normalisation(model, ds, np.random.default_rng(0), n=64)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)

    def loss() -> torch.Tensor:
        pred = model(b["points"], b["u"][:, 0], b["valid"]).points
        return point_loss(pred, b["target"][:, 0], b["target_valid"][:, 0], b["points"])

    first = float(loss().detach())
    for _ in range(250):
        opt.zero_grad()
        loss().backward()
        opt.step()
    model.eval()
    assert float(loss().detach()) < first / 10


def _cfg(tiny_data, out, **kw) -> TrainConfig:
    base = dict(
        data=str(tiny_data), out=str(out), iters=8, batch=4, eval_every=4, val_examples=8, k=3
    )
    return TrainConfig(**{**base, **kw})


def _killed_at_the_second_evaluation(cfg: TrainConfig, monkeypatch) -> None:
    """Train ``cfg`` (evaluated every 4 of 8 steps) until a KeyboardInterrupt at its second
    evaluation, as a kill after the first's checkpoint would leave it."""
    real, calls = train_mod.validate, []

    def interrupt(*args, **kw):
        if calls:
            raise KeyboardInterrupt
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(train_mod, "validate", interrupt)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, progress=False)
    monkeypatch.setattr(train_mod, "validate", real)


def test_resume_gives_the_same_weights_as_an_uninterrupted_run(tiny_data, tmp_path, monkeypatch):
    train(_cfg(tiny_data, tmp_path / "a"), progress=False)
    _killed_at_the_second_evaluation(_cfg(tiny_data, tmp_path / "b"), monkeypatch)
    assert read_checkpoint(tmp_path / "b" / "last.pt")["train_state"]["iteration"] == 4
    with pytest.raises(FileExistsError, match="--resume"):
        train(_cfg(tiny_data, tmp_path / "b"), progress=False)
    with open(tmp_path / "b" / "metrics.jsonl", "a") as f:  # killed while logging iteration 8
        f.write('{"iteration": 8, "train_lo')
    train(_cfg(tiny_data, tmp_path / "b"), resume=True, progress=False)
    a, b = read_checkpoint(tmp_path / "a" / "last.pt"), read_checkpoint(tmp_path / "b" / "last.pt")
    for k in a["state_dict"]:
        assert torch.equal(a["state_dict"][k], b["state_dict"][k]), k
    lines = [json.loads(x) for x in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    assert [x["iteration"] for x in lines] == [4, 8]
    with pytest.raises(InputError, match="other settings"):
        train(_cfg(tiny_data, tmp_path / "b", lr=0.5), resume=True, progress=False)


def test_nan_loss_stops_with_a_clear_message_and_keeps_the_last_good_checkpoint(
    tiny_data, tmp_path, monkeypatch
):
    real = train_mod.point_loss
    calls = []

    def nan_later(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs) * (float("nan") if len(calls) > 5 else 1.0)

    monkeypatch.setattr(train_mod, "point_loss", nan_later)
    with pytest.raises(
        TrainingDiverged,
        match=r"loss became nan at step \d+: train again with a lower --lr into a new --out "
        r"folder; --init .*last.pt starts it from the last good state \(iteration 4\)",
    ):
        train(_cfg(tiny_data, tmp_path), progress=False)
    blob = read_checkpoint(tmp_path / "last.pt")
    assert blob["train_state"]["iteration"] == 4
    assert all(
        torch.isfinite(v).all() for v in blob["state_dict"].values() if v.is_floating_point()
    )


def test_mismatched_checkpoints_are_refused(tiny_data, tmp_path):
    train(_cfg(tiny_data, tmp_path, iters=4), progress=False)
    path = tmp_path / "best.pt"
    tiny = load_scenario("tiny")
    model, blob = load_checkpoint(path, scenario=tiny, variant="se3net")
    assert blob["model"]["height"] == 32 and not model.training
    with pytest.raises(CheckpointError, match="is a 'se3net' model, not 'flow'"):
        load_checkpoint(path, variant="flow")
    with pytest.raises(
        CheckpointError, match=r"camera\.width: model has 32, scenario 'single_box' has 64"
    ):
        load_checkpoint(path, scenario=load_scenario("single_box"))
    with pytest.raises(CheckpointError, match=r"action\.max_speed_m_s"):
        load_checkpoint(path, scenario=with_fields(tiny, "action", max_speed_m_s=0.3))
    broken = tmp_path / "broken.pt"
    broken.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(CheckpointError, match="cannot be read"):
        load_checkpoint(broken)
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.pt")
    (tmp_path / "notes.pt").write_text("hello\n")  # a file torch.save did not write
    with pytest.raises(CheckpointError, match="cannot be read.*not a file torch.save wrote"):
        load_checkpoint(tmp_path / "notes.pt")
    newer = read_checkpoint(path)
    newer["model"] = {**newer["model"], "attention": True}  # from a later version of the code
    torch.save(newer, tmp_path / "newer.pt")
    for read in (load_checkpoint, model_config):
        with pytest.raises(CheckpointError, match=r"code does not know \(attention\)"):
            read(tmp_path / "newer.pt")
    blob = read_checkpoint(path)
    blob["model"] = dataclasses.asdict(ModelConfig(variant="se3net", k=5, height=32, width=32))
    torch.save(blob, tmp_path / "other_k.pt")
    with pytest.raises(CheckpointError, match="does not fit the se3net network"):
        load_checkpoint(tmp_path / "other_k.pt")


def test_bad_training_settings_are_refused(tiny_data, tmp_path):
    with pytest.raises(InputError, match="--iters must be positive"):
        _cfg(tiny_data, tmp_path, iters=0)
    with pytest.raises(InputError, match="--stride must be positive, got 0"):
        _cfg(tiny_data, tmp_path, stride=0)
    with pytest.raises(DataError, match="stride 3 does not divide the 32x32 images"):
        train(_cfg(tiny_data, tmp_path / "s3", stride=3), progress=False)
    with pytest.raises(InputError, match="unknown variant"):
        train(_cfg(tiny_data, tmp_path, variant="huge"), progress=False)
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        train(_cfg(tiny_data, tmp_path / "fresh"), resume=True, progress=False)


def test_eval_writes_the_table_json_and_pictures(tiny_data, tmp_path):
    train(_cfg(tiny_data, tmp_path / "se3", iters=4), progress=False)
    train(_cfg(tiny_data, tmp_path / "flow", iters=4, variant="flow"), progress=False)
    paths = [tmp_path / "se3" / "best.pt", tmp_path / "flow" / "best.pt"]
    results = evaluate(paths, tiny_data, tmp_path / "eval", max_examples=40)
    table = (tmp_path / "eval" / "table.md").read_text()
    assert "se3 (se3net)" in table and "flow (flow)" in table and "no-motion" in table
    figures = json.loads((tmp_path / "eval" / "eval.json").read_text())
    se3 = figures["se3"]
    assert se3["no_motion_mse"] > 0 and se3["ratio_to_no_motion"] == pytest.approx(
        se3["flow_mse"] / se3["no_motion_mse"], rel=1e-6
    )
    assert (
        0 < se3["mask_binariness"] <= 1 and 0 <= se3["iou"] <= 1 and len(se3["multi_step_mse"]) == 5
    )
    assert figures["flow"]["mask_binariness"] is None
    # a model that has barely trained is close to no motion
    assert 0.5 < results[1].ratio_to_no_motion < 1.5
    assert (tmp_path / "eval" / "se3_examples.png").read_bytes()[:4] == b"\x89PNG"


def test_later_fraction_draws_that_share_of_each_batch_from_the_later_folders(tiny_data, tmp_path):
    from se3net.train import draw_batch

    ds = PushDataset([tiny_data, tiny_data], split="train")
    assert (ds.source == 0).sum() == (ds.source == 1).sum() == len(ds) // 2
    rng = np.random.default_rng(0)
    both = (str(tiny_data), str(tiny_data))
    cfg = _cfg(tiny_data, tmp_path, data=both, batch=8, later_fraction=0.75)
    drawn = np.concatenate([draw_batch(ds, cfg, rng) for _ in range(50)])
    assert len(drawn) == 400
    assert (ds.source[drawn] == 1).sum() == 300  # exactly 6 of every 8, not about half
    uniform = np.concatenate(
        [draw_batch(ds, _cfg(tiny_data, tmp_path, data=both, batch=8), rng) for _ in range(50)]
    )
    assert 140 < (ds.source[uniform] == 1).sum() < 260
    with pytest.raises(InputError, match="after the first 1, and there are 1"):
        _cfg(tiny_data, tmp_path, later_fraction=0.5)
    with pytest.raises(InputError, match=r"--later-fraction must be in \[0, 1\)"):
        _cfg(tiny_data, tmp_path, data=both, later_fraction=1.0)


def test_later_from_keeps_several_exploration_folders_out_of_the_later_share(tiny_data, tmp_path):
    """Two exploration folders, then the planner-visited one: the later share is drawn from the
    third folder alone, the rest from the first two (both of them)."""
    from se3net.train import draw_batch

    three = (str(tiny_data),) * 3
    ds = PushDataset(list(three), split="train")
    cfg = _cfg(tiny_data, tmp_path, data=three, batch=8, later_fraction=0.25, later_from=2)
    rng = np.random.default_rng(0)
    drawn = np.concatenate([draw_batch(ds, cfg, rng) for _ in range(50)])
    counts = np.bincount(ds.source[drawn], minlength=3)
    assert counts[2] == 100  # exactly 2 of every 8
    assert counts[0] > 100 and counts[1] > 100  # the other 6 from both exploration folders
    with pytest.raises(InputError, match="after the first 3, and there are 3"):
        _cfg(tiny_data, tmp_path, data=three, later_fraction=0.25, later_from=3)
    with pytest.raises(InputError, match="--later-from must be positive"):
        _cfg(tiny_data, tmp_path, data=three, later_from=0)


def test_runs_have_no_horizon_setting_and_old_runs_with_the_inert_one_resume(tiny_data, tmp_path):
    """Old runs stored a ``horizon`` that at 1 changed nothing, so they resume; any other value
    is refused. So with the retired multi-step training: a run that stored ``rollout_steps``
    1 (and the grid feedback) resumes, one of 3 steps is refused."""
    cfg = _cfg(tiny_data, tmp_path, iters=4)
    train(cfg, progress=False)
    last = tmp_path / "last.pt"
    assert "horizon" not in read_checkpoint(last)["train_state"]["config"]
    with pytest.raises(TypeError):
        TrainConfig(data=str(tiny_data), out=str(tmp_path), horizon=2)
    blob = read_checkpoint(last)
    blob["train_state"]["config"]["horizon"] = 1
    torch.save(blob, last)
    train(cfg, resume=True, progress=False)
    blob["train_state"]["config"]["horizon"] = 3
    torch.save(blob, last)
    with pytest.raises(InputError, match="other settings than the run's .*horizon: the run has 3"):
        train(cfg, resume=True, progress=False)
    del blob["train_state"]["config"]["horizon"]
    blob["train_state"]["config"] |= {"rollout_steps": 1, "feedback": "grid"}
    torch.save(blob, last)
    train(cfg, resume=True, progress=False)
    blob["train_state"]["config"]["rollout_steps"] = 3
    torch.save(blob, last)
    with pytest.raises(InputError, match="rollout_steps: the run has 3"):
        train(cfg, resume=True, progress=False)


def test_a_stride_2_run_is_a_half_resolution_network_refused_where_it_does_not_fit(
    tiny_data, tmp_path
):
    tiny = load_scenario("tiny")
    train(_cfg(tiny_data, tmp_path / "s2", iters=4, stride=2), progress=False)
    path = tmp_path / "s2" / "best.pt"
    model, blob = load_checkpoint(path, scenario=tiny)
    assert (model.cfg.height, model.cfg.width, model.cfg.stride) == (16, 16, 2)
    (result,) = evaluate([str(path)], str(tiny_data), str(tmp_path / "eval"), max_examples=16)
    assert result.examples > 0 and 0 < result.flow_mse < float("inf")
    with pytest.raises(CheckpointError, match="stride: --init has 2, this run has 1"):
        train(_cfg(tiny_data, tmp_path / "s1", iters=4, init=str(path)), progress=False)
    blob["model"]["stride"] = 1  # a stored stride that does not match the network's size
    torch.save(blob, tmp_path / "odd.pt")
    with pytest.raises(CheckpointError, match="16x16 network at pixel stride 1 .* 32x32 camera"):
        load_checkpoint(tmp_path / "odd.pt", scenario=tiny)


def test_checkpoints_from_before_the_stride_setting_are_full_resolution(tiny_data, tmp_path):
    train(_cfg(tiny_data, tmp_path / "a", iters=4), progress=False)
    blob = read_checkpoint(tmp_path / "a" / "best.pt")
    del blob["model"]["stride"]
    torch.save(blob, tmp_path / "old.pt")
    model, _ = load_checkpoint(tmp_path / "old.pt", scenario=load_scenario("tiny"))
    assert model.cfg.stride == 1
    train(_cfg(tiny_data, tmp_path / "b", iters=4, init=str(tmp_path / "old.pt")), progress=False)
    assert read_checkpoint(tmp_path / "b" / "best.pt")["model"]["stride"] == 1
    last = tmp_path / "a" / "last.pt"  # and an old run resumes
    blob = read_checkpoint(last)
    del blob["train_state"]["config"]["stride"]
    torch.save(blob, last)
    train(_cfg(tiny_data, tmp_path / "a", iters=4), resume=True, progress=False)


def test_checkpoints_of_like_named_runs_get_names_that_tell_them_apart(tmp_path):
    from se3net.evaluate import checkpoint_names

    paths = [
        tmp_path / "improve/round_1/model/best.pt",
        tmp_path / "improve/round_3/model/best.pt",
        tmp_path / "runs/sb_se3net/best.pt",
        tmp_path / "runs/snap/iter_002500.pt",
    ]
    assert checkpoint_names(paths) == [
        "round_1/model",
        "round_3/model",
        "sb_se3net",
        "iter_002500",
    ]
    # checkpoints that are not a run's best or last are told apart by their own folders
    assert checkpoint_names([tmp_path / "c1/model.pt", tmp_path / "c2/model.pt"]) == [
        "c1/model",
        "c2/model",
    ]
    snaps = [
        tmp_path / "r1/iter_000003.pt",
        tmp_path / "r2/iter_000003.pt",
        tmp_path / "r2/best.pt",
    ]
    assert checkpoint_names(snaps) == ["r1/iter_000003", "r2/iter_000003", "r2"]
    with pytest.raises(InputError, match="given twice"):
        checkpoint_names([tmp_path / "c1/model.pt", tmp_path / "c1/model.pt"])


def test_the_split_loss_does_not_grow_with_the_static_background_the_moving_one_does():
    # one moving point predicted exactly, static points all off by 1 mm: with the moving
    # normalisation, twice the background costs twice as much (so a net is paid to shrink
    # every motion); split into means, the background's share stays the same
    def scene(n_static: int) -> tuple[torch.Tensor, ...]:
        n = 1 + n_static
        points = torch.zeros(1, 3, 1, n)
        target = points.clone()
        target[0, 0, 0, 0] = 0.02  # the moving point
        pred = target.clone()
        pred[0, 2, 0, 1:] += 0.001
        return pred, target, torch.ones(1, 1, n, dtype=torch.bool), points

    small, big = (float(point_loss(*scene(n))) for n in (50, 100))
    assert big > 1.5 * small > 0


def test_runs_record_their_noise_and_options_and_resume_only_with_them(tiny_data, tmp_path):
    opts = dict(noise="assoc-9", variant="flow")
    train(_cfg(tiny_data, tmp_path / "r", **opts), progress=False)
    blob = read_checkpoint(tmp_path / "r" / "last.pt")
    assert {k: blob["train_state"]["config"][k] for k in opts} == opts
    with pytest.raises(InputError, match="noise"):
        train(_cfg(tiny_data, tmp_path / "r", **{**opts, "noise": "none"}), resume=True,
              progress=False)  # fmt: skip


def test_noisy_validation_is_worse_than_clean_for_the_same_weights(tiny_data, tmp_path):
    train(_cfg(tiny_data, tmp_path / "c", iters=40, eval_every=40), progress=False)
    from se3net.evaluate import evaluate_checkpoint

    ck = tmp_path / "c" / "best.pt"
    clean = evaluate_checkpoint(ck, tiny_data, max_examples=40)
    noisy = evaluate_checkpoint(ck, tiny_data, max_examples=40, noise="depth")
    assert noisy.noise == "depth" and clean.noise == "none"
    assert noisy.no_motion_mse > clean.no_motion_mse  # 1.5 cm of depth noise on the targets
    assert noisy.flow_mse > clean.flow_mse


def test_a_snapshot_is_written_before_the_state_a_resume_starts_from(tiny_data, tmp_path,
                                                                     monkeypatch):  # fmt: skip
    real, out = train_mod.save_checkpoint, tmp_path / "run"

    def killed_writing_the_snapshot(path, *args, **kwargs):
        if path.name == "iter_000008.pt":
            raise KeyboardInterrupt  # as a kill between the run's files would
        return real(path, *args, **kwargs)

    cfg = _cfg(tiny_data, out, keep_every=8)  # evaluated at 4 and 8, a snapshot at 8
    monkeypatch.setattr(train_mod, "save_checkpoint", killed_writing_the_snapshot)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, progress=False)
    monkeypatch.setattr(train_mod, "save_checkpoint", real)
    train(cfg, resume=True, progress=False)  # from the state before the snapshot, not after
    assert sorted(p.name for p in out.glob("iter_*.pt")) == ["iter_000008.pt"]


def test_a_negative_keep_every_is_refused():
    with pytest.raises(InputError, match="--keep-every must be 0 \\(no snapshots\\) or more"):
        TrainConfig(data="d", out="o", keep_every=-1)


@pytest.fixture(scope="module")
def start_on_other_data(tmp_path_factory):
    """A tiny dataset other than ``tiny_data``, and a checkpoint trained on it (a start to
    fine-tune from)."""
    from sim.dataset import DataConfig, generate

    root = tmp_path_factory.mktemp("other")
    other = root / "data"
    generate(DataConfig("tiny", episodes=21, steps_per_episode=8, episodes_per_shard=7, seed=5),
             other, progress=False)  # fmt: skip
    train(_cfg(other, root / "start", iters=4), progress=False)
    return other, root / "start" / "best.pt"


def test_a_fine_tuned_model_remembers_the_data_its_start_learnt_from(
    tiny_data, tmp_path, start_on_other_data
):
    from se3net.checkpoint import refuse_trained_on
    from sim.datastore import read_manifest

    other, start = start_on_other_data
    train(_cfg(tiny_data, tmp_path / "tuned", iters=4, init=str(start)), progress=False)
    tuned = tmp_path / "tuned" / "best.pt"
    with pytest.raises(CheckpointError, match="was trained on"):  # its start learnt from other
        refuse_trained_on([tuned], read_manifest(other), other)
    with pytest.raises(CheckpointError, match="was trained on"):  # and it from tiny_data
        refuse_trained_on([tuned], read_manifest(tiny_data), tiny_data)


def test_a_fine_tuning_run_from_before_its_start_was_recorded_resumes(
    tiny_data, tmp_path, monkeypatch, start_on_other_data
):
    from se3net.checkpoint import manifest_hash
    from sim.datastore import read_manifest

    _, start = start_on_other_data  # it learnt from other data than the fine-tuning's
    cfg = _cfg(tiny_data, tmp_path / "tuned", init=str(start))
    _killed_at_the_second_evaluation(cfg, monkeypatch)
    last = tmp_path / "tuned" / "last.pt"
    blob = read_checkpoint(last)
    blob["data_hash"] = manifest_hash(read_manifest(tiny_data))  # as such runs recorded it
    torch.save(blob, last)
    train(cfg, resume=True, progress=False)
    assert read_checkpoint(last)["train_state"]["iteration"] == 8


def test_a_moved_run_resumes_with_its_data_spelt_another_way(tiny_data, tmp_path, monkeypatch):
    _killed_at_the_second_evaluation(_cfg(tiny_data, tmp_path / "run"), monkeypatch)
    (tmp_path / "run").rename(tmp_path / "moved")
    train(_cfg(f"{tiny_data}/.", tmp_path / "moved"), resume=True, progress=False)
    assert read_checkpoint(tmp_path / "moved" / "last.pt")["train_state"]["iteration"] == 8
