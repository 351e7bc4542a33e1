import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

import evaluation.improve as improve_mod
import scenarios
from evaluation.improve import ImproveConfig, run_improve
from evaluation.trials import draw_trial
from planner.presets import preset_settings
from scenarios import InputError
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
    base = dict(scenarios="tiny", model=start_model, data=str(tiny_data), rounds=1,
                trials_per_round=2, heldout=2, max_steps=3, finetune_iters=2, eval_every=2,
                batch=4)  # fmt: skip
    return ImproveConfig(**{**base, **kw})


def test_a_round_adds_exact_planner_episodes_and_leaves_the_heldout_set_alone(
    tiny, tiny_data, start_model, tmp_path
):
    cfg = _cfg(tiny_data, start_model)
    result = run_improve(cfg, tmp_path / "imp")
    data = tmp_path / "imp" / "round_1" / "data" / "tiny"
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
        [json.loads(x)["goal"] for x in (tmp_path / "imp" / f"round_{r}" / "heldout" / "tiny" /
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
        improve_mod.collect(cfg, "tiny", "oracle", 1, tmp_path / name, jobs=jobs)
    a, b = (read_manifest(tmp_path / n)["shards"] for n in ("local", "ray"))
    assert a["shard_00000.npz"]["sha256"] == b["shard_00000.npz"]["sha256"]
    assert (tmp_path / "ray" / "shard_00000.npz").read_bytes() == (
        tmp_path / "local" / "shard_00000.npz"
    ).read_bytes()


def test_rounds_over_several_scenarios_collect_in_each_and_measure_the_held_out_one_too(
    tiny_data, start_model, tmp_path, monkeypatch
):
    """Pushes are collected in every --scenario (each folder with its own scenario's objects),
    the --measure-only scenario is measured every round and never collected in, and the
    fine-tuning pools every exploration folder and draws the visited share from the rest."""
    from scenarios import load_scenario
    from sim.datastore import scenario_of

    text = (Path(scenarios.__file__).parent / "tiny.toml").read_text()
    cylinder, heavy = tmp_path / "tiny_cylinder.toml", tmp_path / "tiny_heavy.toml"
    cylinder.write_text(text.replace('shapes = ["box"]', 'shapes = ["cylinder"]'))
    heavy.write_text(text.replace("mass_kg = [0.2, 0.2]", "mass_kg = [0.4, 0.4]"))
    assert load_scenario(str(cylinder)).objects.shapes == ("cylinder",)
    exploration = (str(tiny_data), str(tiny_data))
    cfg = _cfg(tiny_data, start_model, scenarios=("tiny", str(cylinder)), data=exploration,
               measure_only=(str(heavy),), trials_per_round=1, heldout=1)  # fmt: skip
    pooled = []
    real_finetune = improve_mod.finetune
    monkeypatch.setattr(improve_mod, "finetune",
                        lambda c, init, data, out: pooled.append(list(data)) or
                        real_finetune(c, init, data, out))  # fmt: skip
    result = run_improve(cfg, tmp_path / "imp")
    root = tmp_path / "imp"
    for name, shape in (("tiny", "box"), ("tiny_cylinder", "cylinder")):
        manifest = read_manifest(root / "round_1" / "data" / name)
        assert scenario_of(manifest).objects.shapes == (shape,)
        assert manifest["stats"]["mode_steps"][PLANNER_MODE] > 0
    assert not (root / "round_1" / "data" / "tiny_heavy").exists()
    visited = [str(root / "round_1" / "data" / n) for n in ("tiny", "tiny_cylinder")]
    assert pooled == [[*exploration, *visited]]
    run = read_checkpoint(root / "round_1" / "model" / "last.pt")["train_state"]["config"]
    assert run["later_from"] == 2 and run["later_fraction"] == cfg.visited_fraction
    names = ["tiny", "tiny_cylinder", "tiny_heavy"]
    assert [(r["round"], r["scenario"]) for r in result["rounds"]] == [
        (r, n) for r in (0, 1) for n in names
    ]
    assert [r.get("new_episodes") for r in result["rounds"][3:]] == [
        read_manifest(root / "round_1" / "data" / "tiny")["identity"]["episodes"],
        read_manifest(root / "round_1" / "data" / "tiny_cylinder")["identity"]["episodes"],
        0,
    ]
    for r in (0, 1):
        for n in names:
            assert len((root / f"round_{r}" / "heldout" / n / "trials.jsonl").read_text()
                       .splitlines()) == 1  # fmt: skip
    table = (root / "improve.md").read_text()
    assert table.count("\n| ") == 6 and "| tiny_heavy |" in table


def test_the_same_scenario_twice_is_refused_before_anything_is_written(
    tiny_data, start_model, tmp_path
):
    cfg = _cfg(tiny_data, start_model, scenarios=("tiny",), measure_only=("tiny",))
    with pytest.raises(ValueError, match="each scenario once"):
        run_improve(cfg, tmp_path / "imp")
    assert not (tmp_path / "imp").exists()


@pytest.mark.parametrize(("field", "value", "message"), [
    ("lr", 0.0, "--lr must be a positive number, got 0.0"),
    ("lr", float("nan"), "--lr must be a positive number, got nan"),
    ("batch", 0, "--batch must be positive, got 0"),
    ("eval_every", -1, "--eval-every must be positive, got -1"),
])  # fmt: skip
def test_fine_tuning_settings_are_refused_before_round_0_runs(field, value, message):
    with pytest.raises(InputError, match=message):  # the config, before any trial or file
        ImproveConfig(scenarios="tiny", model="m", data="d", **{field: value})


def test_a_run_from_before_the_planner_options_continues_as_the_planner_before(
    tiny_data, start_model, tmp_path
):
    """An improve folder written before its planner settings were recorded (schema 1: no
    ``plan``, none of ``feedback``, ``contact_margin_m``, ``shaping_fade``, ``horizon``,
    ``keepout_weight`` and ``near_goal_m``) planned as the ``fade_behind`` planner's
    predecessor: on the grid with no gate, the shaping faded everywhere, 4 steps ahead, no
    keep-out term and no fade near the goal, that is the ``grid`` preset. It is refused with
    today's defaults and continues with that preset."""
    cfg = _cfg(tiny_data, start_model)
    meta = {k: v for k, v in dataclasses.asdict(cfg).items() if k != "plan"}
    (tmp_path / "imp").mkdir()
    (tmp_path / "imp" / "config.json").write_text(json.dumps({**meta, "planner": "cem"}))
    with pytest.raises(ValueError, match="rollout.feedback: folder has 'grid'"):
        run_improve(cfg, tmp_path / "imp")
    before = dataclasses.replace(cfg, plan=preset_settings("grid"))
    assert run_improve(before, tmp_path / "imp")["rounds"]
    trials = json.loads((tmp_path / "imp" / "round_0" / "heldout" / "tiny" / "config.json")
                        .read_text())  # fmt: skip
    plan = trials["plan"]
    assert plan["cost"]["shaping_fade"] == "everywhere" and plan["optimiser"]["horizon_s"] == 0.6
    assert plan["cost"]["w_keepout"] == 0.0 and plan["cost"]["near_goal_m"] == 0.0
    assert plan["rollout"] == {"feedback": "grid", "contact_margin_m": None}


def test_finetuning_keeps_the_starting_network(tiny_data, tmp_path):
    """A model of other masks and another variant than the defaults is fine-tuned as that
    network (the defaults would build another, which init refuses)."""
    start = tmp_path / "start"
    train(TrainConfig(data=str(tiny_data), out=str(start), iters=2, batch=4, eval_every=2,
                      val_examples=8, k=5, variant="no-penalty"), progress=False)  # fmt: skip
    cfg = _cfg(tiny_data, str(start / "best.pt"), data=(str(tiny_data), str(tiny_data)))
    best = improve_mod.finetune(cfg, str(start / "best.pt"), list(cfg.data) * 2, tmp_path / "ft")
    blob = read_checkpoint(best)
    assert blob["model"]["k"] == 5 and blob["model"]["variant"] == "no-penalty"
    run = read_checkpoint(tmp_path / "ft" / "last.pt")["train_state"]["config"]
    assert run["init"] == str(start / "best.pt")


def test_each_planner_episode_counts_only_its_own_qp_failures(tiny_data, start_model, monkeypatch):
    """The world counts the controller's QP failures since its reset; a push cut into several
    episodes gives each the failures of its own steps, so the dataset's total is the push's."""

    class _Result:
        def summary(self):
            return {}

    def fake_push(push, *, on_transition):
        world = PushWorld(scenarios.load_scenario("tiny"))
        obs = world.reset(push.seed)
        on_transition(world, obs, None)
        for _ in range(5):
            world.controller.failures += 1  # one failure in every step
            action = np.zeros(len(world.layout.commands))
            obs = world.step(action)
            on_transition(world, obs, action)
        return _Result()

    monkeypatch.setattr(improve_mod, "run_push", fake_push)
    cfg = _cfg(tiny_data, start_model)
    rec = improve_mod.record_trial(cfg, "tiny", start_model, 0, 0, steps_per_episode=2)
    counts = [int(ep["qp_failures"]) for ep in rec["episodes"]]
    assert counts == [2, 2, 1]
