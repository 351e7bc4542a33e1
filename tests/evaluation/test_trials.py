import json
from dataclasses import replace
from importlib import resources

import numpy as np
import pytest

import evaluation.trials as trials_mod
from evaluation.trials import TrialsConfig, draw_trial, run_trials, wilson
from planner import CostConfig, PlannerConfig, PlanSettings, RolloutConfig
from scenarios import InputError, load_scenario
from se3push.cli import main
from sim import PushWorld
from sim.planar import pose_errors

TIMING = ("replan_ms_median",)


def _strip(rec):
    return {k: v for k, v in rec.items() if k not in TIMING}


def _plan(**sections) -> PlanSettings:
    """Today's settings with some sections replaced (``optimiser=``, ``cost=``, ``rollout=``,
    ``planner=``)."""
    return replace(PlanSettings(), **sections)


def _as_schema_1(folder, drop=(), **old_fields):
    """Rewrite ``folder``'s config.json as folders were written before the one settings object
    (no schema: ``planner``, ``planning``, ``cost`` and the rollout settings at the top),
    without the schema-1 keys ``drop`` names (``"cost.w_keepout"``, ``"feedback"``…) and with
    ``old_fields`` added (``motion_gain=True``…)."""
    meta = json.loads((folder / "config.json").read_text())
    plan = meta.pop("plan")
    del meta["schema"], meta["retired"]
    flat = {k: plan["rollout"][k] for k in ("feedback", "contact_margin_m")}  # schema 1's
    old = {**meta, "planner": plan["planner"], "planning": plan["optimiser"], "cost": plan["cost"],
           **flat, "motion_gain": "off", **old_fields}  # fmt: skip
    for key in drop:
        *path, name = key.split(".")
        node = old
        for part in path:
            node = node[part]
        del node[name]
    (folder / "config.json").write_text(json.dumps(old))


def test_goals_follow_the_scenario_distribution():
    s = load_scenario("single_box")
    g = s.goals
    for i in range(20):
        t = draw_trial(s, 0, i)
        (x, y, _), (sx, sy, _) = t["goal"], t["start"]
        dist = ((x - sx) ** 2 + (y - sy) ** 2) ** 0.5
        assert g.region_m[0] <= x <= g.region_m[1] and g.region_m[2] <= y <= g.region_m[3]
        assert dist <= g.max_distance_m + 1e-9
    assert draw_trial(s, 0, 3) == draw_trial(s, 0, 3) and draw_trial(s, 0, 3) != draw_trial(s, 1, 3)


def test_goals_are_as_far_as_specified_under_the_objects_symmetry():
    """A goal's turn is measured as success measures it (a box repeats every 180°): no goal
    is both nearer than min_distance_m and turned less than min_yaw_deg."""
    s = load_scenario("single_box")
    g = s.goals
    for i in range(200):
        t = draw_trial(s, 0, i)
        world = PushWorld(s)
        world.reset(t["reset_seed"])
        dist, turn = pose_errors(np.array(t["goal"]), np.array(t["start"]),
                                 world.objects[0].yaw_period_rad)  # fmt: skip
        assert dist >= g.min_distance_m or turn >= g.min_yaw_deg, (i, dist, turn)


def test_a_folder_of_another_trial_draw_is_refused(tmp_path):
    cfg = TrialsConfig("tiny", n=1, model="no-motion", max_steps=1)
    run_trials(cfg, tmp_path, progress=False)
    meta = tmp_path / "config.json"
    old = json.loads(meta.read_text())
    old.pop("trial_set")  # as written before goals were drawn with the object's symmetry
    meta.write_text(json.dumps(old))
    with pytest.raises(ValueError, match="trial_set"):
        run_trials(cfg, tmp_path, progress=False)


def test_the_trial_set_is_the_same_for_two_models(tmp_path):
    keys = ("trial", "reset_seed", "start", "goal")
    sets = []
    for model in ("no-motion", "oracle"):
        run_trials(
            TrialsConfig("tiny", n=2, model=model, max_steps=1), tmp_path / model, progress=False
        )
        lines = (tmp_path / model / "trials.jsonl").read_text().splitlines()
        sets.append([{k: json.loads(x)[k] for k in keys} for x in lines])
    assert sets[0] == sets[1]


def test_a_resumed_run_gives_the_same_results(tmp_path, monkeypatch):
    cfg = TrialsConfig("tiny", n=3, model="no-motion", max_steps=4)
    ref = run_trials(cfg, tmp_path / "ref", progress=False)
    real = trials_mod.run_trial

    def interrupted(c, i):
        if i == 1:
            raise KeyboardInterrupt
        return real(c, i)

    monkeypatch.setattr(trials_mod, "run_trial", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_trials(cfg, tmp_path / "b", progress=False)
    monkeypatch.setattr(trials_mod, "run_trial", real)
    done = []
    monkeypatch.setattr(trials_mod, "run_trial", lambda c, i: done.append(i) or real(c, i))
    again = run_trials(cfg, tmp_path / "b", progress=False)
    assert done == [1, 2]  # trial 0 was not run again
    a = [
        _strip(json.loads(x)) for x in (tmp_path / "ref" / "trials.jsonl").read_text().splitlines()
    ]
    b = [_strip(json.loads(x)) for x in (tmp_path / "b" / "trials.jsonl").read_text().splitlines()]
    assert a == b
    assert again["success_tight"] == ref["success_tight"] and again["trials"] == 3
    assert (tmp_path / "b" / "paths.png").read_bytes()[:4] == b"\x89PNG"
    prefix = run_trials(TrialsConfig("tiny", n=2, model="no-motion", max_steps=4), tmp_path / "b",
                        progress=False)  # fmt: skip
    assert done == [1, 2] and prefix["trials"] == 2  # summarised from the finished trials
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["trials"] == 3  # kept
    assert prefix["diagnostics"]["still_steps"] + prefix["diagnostics"]["moved_steps"] <= 2 * 4
    with pytest.raises(ValueError, match="holds other trials"):
        run_trials(
            TrialsConfig("tiny", n=3, model="oracle", max_steps=4), tmp_path / "b", progress=False
        )


def test_wilson_interval():
    lo, hi = wilson(19, 20)
    assert lo == pytest.approx(0.7639, abs=1e-4) and hi == pytest.approx(0.9911, abs=1e-4)
    assert wilson(0, 10)[0] == 0.0


def test_trials_command_and_bad_input(tmp_path, capsys):
    out = tmp_path / "t"
    assert (
        main(
            [
                "trials",
                "--scenario",
                "tiny",
                "--n",
                "1",
                "--model",
                "no-motion",
                "--max-steps",
                "2",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "success (2 cm, 10 deg)" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text())["trials"] == 1
    assert main(["trials", "--scenario", "tiny", "--n", "2", "--model", "no-motion",
                 "--max-steps", "2", "--out", str(out)]) == 0  # fmt: skip
    assert f"wrote {out}/trials.jsonl, summary.json" in capsys.readouterr().out
    assert main(["trials", "--scenario", "tiny", "--n", "1", "--model", "no-motion",
                 "--max-steps", "2", "--out", str(out)]) == 0  # fmt: skip
    said = capsys.readouterr().out
    assert f"summarised the first 1 of the 2 trials in {out}; its files are unchanged" in said
    assert "wrote" not in said
    assert json.loads((out / "summary.json").read_text())["trials"] == 2
    assert main(["trials", "--scenario", "tiny", "--n", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--n and --max-steps must be positive" in capsys.readouterr().err


def test_a_folder_of_other_planning_settings_is_refused(tmp_path):
    cfg = TrialsConfig("tiny", n=1, model="no-motion", max_steps=1)
    run_trials(cfg, tmp_path, progress=False)
    assert run_trials(replace(cfg, n=2), tmp_path, progress=False)["trials"] == 2
    with pytest.raises(InputError, match="cost.w_spread"):
        run_trials(replace(cfg, plan=_plan(cost=CostConfig(w_spread=0.0))), tmp_path,
                   progress=False)  # fmt: skip
    with pytest.raises(InputError, match="optimiser.horizon"):
        run_trials(replace(cfg, plan=_plan(optimiser=PlannerConfig(horizon_s=0.3))), tmp_path,
                   progress=False)  # fmt: skip
    # a setting only another optimiser reads does not make other trials, even a setting the
    # folder's code did not have yet
    meta = json.loads((tmp_path / "config.json").read_text())
    del meta["plan"]["optimiser"]["grad_starts"]
    (tmp_path / "config.json").write_text(json.dumps(meta))
    grad = PlannerConfig(grad_starts=2, trust_radius=0.1, temperature=0.1)
    run = run_trials(replace(cfg, n=3, plan=_plan(optimiser=grad)), tmp_path, progress=False)
    assert run["trials"] == 3
    # nor does the planner's seed, which each trial replaces by its world's
    reseeded = _plan(optimiser=PlannerConfig(seed=5))
    assert run_trials(replace(cfg, n=4, plan=reseeded), tmp_path, progress=False)["trials"] == 4
    run_trials(replace(cfg, plan=_plan(planner="grad")), tmp_path / "g", progress=False)
    with pytest.raises(InputError, match="optimiser.grad_starts: folder has 4, this run asks f"):
        run_trials(replace(cfg, plan=_plan(planner="grad", optimiser=grad)), tmp_path / "g",
                   progress=False)  # fmt: skip
    with pytest.raises(InputError, match="cost.w_spread must be a finite number"):
        CostConfig(w_spread=float("nan"))
    with pytest.raises(InputError, match="pos_scale_m must be positive"):
        CostConfig(pos_scale_m=0.0)


def _threads_record(cfg, i):
    import torch

    return {"trial": i, "threads": torch.get_num_threads(), "success_tight": False}


@pytest.mark.parametrize(
    ("workers", "threads", "expected"), [(2, None, 1), (1, None, 1), (2, 3, 3)]
)
def test_each_trial_worker_runs_with_the_threads_asked_for(workers, threads, expected, monkeypatch,
                                                          tmp_path):  # fmt: skip
    """Trial workers get one torch thread each unless told otherwise (two workers on two cores
    with two threads each would fight, and records would depend on the number of workers)."""
    import torch

    monkeypatch.setattr(trials_mod, "run_trial", _threads_record)
    monkeypatch.setattr(trials_mod, "summarize", lambda records: {"trials": len(records)})
    monkeypatch.setattr(trials_mod, "plot_paths", lambda *a, **k: None)
    before = torch.get_num_threads()
    cfg = TrialsConfig("tiny", n=2, model="no-motion", max_steps=1)
    run_trials(cfg, tmp_path, workers=workers, threads=threads, progress=False)
    lines = (tmp_path / "trials.jsonl").read_text().splitlines()
    assert {json.loads(line)["threads"] for line in lines} == {expected}
    assert torch.get_num_threads() == before  # the caller's setting is restored
    with pytest.raises(InputError, match="--threads must be at least 1"):
        run_trials(cfg, tmp_path / "x", workers=1, threads=0, progress=False)


def test_a_folder_is_refused_when_its_model_names_other_weights_now(tiny_data, tmp_path):
    """A model name (a path, or a shipped name such as ``default``) may come to mean other
    weights; the folder records the weights' SHA-256 and refuses to mix them."""
    from se3net.train import TrainConfig, train

    for seed in (0, 1):
        run = TrainConfig(data=str(tiny_data), out=str(tmp_path / f"m{seed}"), iters=2, batch=4,
                          eval_every=2, val_examples=4, k=3, seed=seed)  # fmt: skip
        train(run, progress=False)
    model = tmp_path / "model.pt"
    model.write_bytes((tmp_path / "m0" / "best.pt").read_bytes())
    cfg = TrialsConfig("tiny", n=1, model=str(model), max_steps=1)
    run_trials(cfg, tmp_path / "t", progress=False)
    meta = json.loads((tmp_path / "t" / "config.json").read_text())
    assert len(meta["model_sha256"]) == 64
    model.write_bytes((tmp_path / "m1" / "best.pt").read_bytes())
    with pytest.raises(InputError, match="model_sha256: folder has"):
        run_trials(replace(cfg, n=2), tmp_path / "t", progress=False)


def test_an_old_folder_of_a_shipped_model_name_is_refused_and_of_a_lone_object_extends(tmp_path):
    """Folders from before weights were recorded: a shipped name (``default``) may mean other
    weights now, so they are refused; the disturbance weight does not matter alone."""
    cfg = TrialsConfig("single_box", n=1, model="default", max_steps=1)
    run_trials(cfg, tmp_path / "old", progress=False)
    _as_schema_1(tmp_path / "old", drop=("model_sha256", "cost.w_disturb"))
    with pytest.raises(InputError, match="predates the record of its model's weights"):
        run_trials(replace(cfg, n=2), tmp_path / "old", progress=False)
    lone = TrialsConfig("single_box", n=1, model="no-motion", max_steps=1)
    run_trials(lone, tmp_path / "lone", progress=False)
    _as_schema_1(tmp_path / "lone", drop=("model_sha256", "cost.w_disturb"))
    assert run_trials(replace(lone, n=2), tmp_path / "lone", progress=False)["trials"] == 2


def test_summaries_count_successes_by_the_pushed_objects_shape_mass_and_size():
    from evaluation.trials import summarize
    from planner.diagnostics import exploitation

    def rec(shape, mass, tight, loose, size=(0.08, 0.06, 0.05)):
        obj = {"shape": shape, "mass_kg": mass, "size_m": list(size)}
        return {"success_tight": tight, "success_loose": loose, "final_pos_err_m": 0.0,
                "final_yaw_err_deg": 0.0, "steps": 1, "replan_ms_median": 1.0,
                "diagnostics": exploitation([]), "pushed_object": obj}  # fmt: skip

    s = summarize([rec("T", 0.52, True, True, (0.07, 0.095, 0.05)),
                   rec("T", 0.7, False, True, (0.09, 0.08, 0.05)),
                   rec("box", 0.3, False, False, (0.06, 0.124, 0.05)),
                   rec("box", 0.58, True, True, (0.10, 0.09, 0.05))])  # fmt: skip
    assert s["by_shape"] == {"T": {"tight": 1, "loose": 2, "trials": 2},
                             "box": {"tight": 1, "loose": 1, "trials": 2}}  # fmt: skip
    # 0.3 kg is a bin's lower edge, though 0.3 / 0.1 is 2.9999999999999996 in floats
    assert s["by_mass"] == {"0.3-0.4 kg": {"tight": 0, "loose": 0, "trials": 1},
                            "0.5-0.6 kg": {"tight": 2, "loose": 2, "trials": 2},
                            "0.7-0.8 kg": {"tight": 0, "loose": 1, "trials": 1}}  # fmt: skip
    # by the footprint's longer side (x or y, never the height), 10 cm on the bin it starts,
    # the bins in the order of their sizes, not of their text
    assert list(s["by_size"].items()) == [
        ("8-10 cm", {"tight": 1, "loose": 2, "trials": 2}),
        ("10-12 cm", {"tight": 1, "loose": 1, "trials": 1}),
        ("12-14 cm", {"tight": 0, "loose": 0, "trials": 1}),
    ]


def test_path_efficiency_is_the_share_of_the_objects_travel_that_nears_the_goal():
    """One trial pushes the object straight at the goal, one pushes it away and back: of the
    4 cm travelled in all, 2 cm brought an object nearer. Records without per-step figures
    (from before they were kept) are left out, and an object that never moved has none."""
    from evaluation.trials import summarize
    from planner.diagnostics import exploitation, step_figures

    goal = np.array([0.1, 0.0, 0.0])

    def rec(*xs, per_step=True):
        poses = [np.array([x, 0.0, 0.0]) for x in xs]
        steps = [step_figures(a, a, b, goal) for a, b in zip(poses[:-1], poses[1:], strict=True)]
        r = {"success_tight": False, "success_loose": False, "final_pos_err_m": 0.0,
             "final_yaw_err_deg": 0.0, "steps": len(steps), "replan_ms_median": 1.0,
             "diagnostics": exploitation(steps)}  # fmt: skip
        return {**r, "per_step": steps} if per_step else r

    straight, back = rec(0.0, 0.01, 0.02), rec(0.0, -0.01, 0.0)
    assert summarize([straight])["path_efficiency"] == pytest.approx(1.0)
    assert summarize([straight, back])["path_efficiency"] == pytest.approx(0.5)
    assert summarize([straight, back, rec(0.0, 0.05, per_step=False)])[
        "path_efficiency"
    ] == pytest.approx(0.5)
    assert summarize([rec(0.0, 0.0, 0.0)])["path_efficiency"] is None


def test_summaries_give_the_share_of_steps_planned_without_seeing_the_pusher():
    """Pooled over the successes and over the failures apart; records from before the figure
    was kept are left out, and a set with none of them has none."""
    from evaluation.trials import summarize

    def rec(won, seen):
        step = {"actual_progress_m": 0.0, "actual_disp_m": 0.0}
        steps = [step] if seen is None else [{**step, "pusher_seen": s} for s in seen]
        return {"success_tight": won, "success_loose": won, "final_pos_err_m": 0.0,
                "final_yaw_err_deg": 0.0, "steps": 1, "replan_ms_median": 1.0,
                "diagnostics": {k: 0 for k in ("still_steps", "phantom_steps", "moved_steps",
                                               "missed_steps", "predicted_progress_m",
                                               "actual_progress_m")},
                "per_step": steps}  # fmt: skip

    failures = [rec(False, [True, False]), rec(False, [False, False, True, True, True, True])]
    s = summarize([rec(True, [True] * 4), *failures, rec(False, None)])
    assert s["pusher_unseen_successes"] == 0.0
    assert s["pusher_unseen_failures"] == pytest.approx(3 / 8)
    assert summarize([rec(True, None)])["pusher_unseen_successes"] is None


@pytest.mark.scale
def test_ray_gives_the_same_records_as_the_local_pool_and_resumes(ray_local, tmp_path):
    """The same trial set on the local pool and on Ray (2 workers): the same records, in trial
    order, apart from the wall-clock replan time; a Ray run extends a local folder."""
    cfg = TrialsConfig(
        "tiny",
        n=3,
        model="oracle",
        max_steps=3,
        plan=_plan(optimiser=PlannerConfig(samples=16, iterations=2, elites=4)),
    )
    run_trials(cfg, tmp_path / "local", workers=2, progress=False)
    run_trials(cfg, tmp_path / "ray", workers=2, backend="ray", progress=False)
    run_trials(replace(cfg, n=1), tmp_path / "resumed", progress=False)
    run_trials(cfg, tmp_path / "resumed", workers=2, backend="ray", progress=False)

    def lines(name):
        return [_strip(json.loads(x))
                for x in (tmp_path / name / "trials.jsonl").read_text().splitlines()]  # fmt: skip

    assert [r["trial"] for r in lines("ray")] == [0, 1, 2]
    assert lines("ray") == lines("local") == lines("resumed")
    assert main(["trials", "--scenario", "tiny", "--n", "1", "--model", "no-motion",
                 "--out", str(tmp_path / "x"), "--address", "auto"]) == 2  # fmt: skip


def test_the_contact_margin_makes_other_trials_of_a_learned_model_only(tmp_path):
    """A folder planned with one contact margin is not extended with another (or none); a
    folder from before the gate had none; the simulator backends ignore it."""
    gated = _plan(rollout=RolloutConfig(contact_margin_m=0.01))
    ungated = _plan(rollout=RolloutConfig(contact_margin_m=None))
    cfg = TrialsConfig("single_box", n=1, model="default", max_steps=1, plan=gated)
    run_trials(cfg, tmp_path / "gated", progress=False)
    with pytest.raises(InputError, match="contact_margin_m: folder has 0.01, this run asks for"):
        run_trials(replace(cfg, n=2, plan=ungated), tmp_path / "gated", progress=False)
    old = replace(cfg, plan=ungated)
    run_trials(old, tmp_path / "old", progress=False)
    _as_schema_1(tmp_path / "old", drop=("contact_margin_m",))
    assert run_trials(replace(old, n=2), tmp_path / "old", progress=False)["trials"] == 2
    still = TrialsConfig("tiny", n=1, model="no-motion", max_steps=1, plan=gated)
    run_trials(still, tmp_path / "still", progress=False)
    assert run_trials(replace(still, n=2, plan=ungated), tmp_path / "still",
                      progress=False)["trials"] == 2  # fmt: skip
    with pytest.raises(InputError, match="rollout.contact_margin_m must be a distance >= 0"):
        RolloutConfig(contact_margin_m=-0.01)


@pytest.mark.parametrize(("recorded", "extends"), [("off", True), (False, True), (None, True),
                                                   ("online", False), (True, False),
                                                   ("contact", False)])  # fmt: skip
def test_a_folder_that_used_the_retired_motion_gain_is_read_but_not_extended(
    recorded, extends, tmp_path
):
    """The motion gain (tried, not kept) left the package: a folder that planned without it
    (off, recorded as false before it had three values, or not recorded at all) extends; one
    that used it holds other trials and is refused, naming the retired option."""
    cfg = TrialsConfig("single_box", n=1, model="default", max_steps=1)
    run_trials(cfg, tmp_path / "old", progress=False)
    _as_schema_1(tmp_path / "old", **({} if recorded is None else {"motion_gain": recorded}))
    if recorded is None:
        meta = json.loads((tmp_path / "old" / "config.json").read_text())
        del meta["motion_gain"]
        (tmp_path / "old" / "config.json").write_text(json.dumps(meta))
    if extends:
        assert run_trials(replace(cfg, n=2), tmp_path / "old", progress=False)["trials"] == 2
    else:
        with pytest.raises(InputError, match="retired.motion_gain: folder has"):
            run_trials(replace(cfg, n=2), tmp_path / "old", progress=False)


def test_a_folder_from_before_the_shaping_fade_continues_only_as_everywhere(tmp_path):
    """Records from before the shaping fade was a setting faded the shaping term everywhere:
    such a folder extends with ``everywhere`` and is refused with the default; a bad setting is
    refused (exit 2 from the command line)."""
    cfg = TrialsConfig("tiny", n=1, model="no-motion", max_steps=1,
                       plan=_plan(cost=CostConfig(shaping_fade="everywhere")))  # fmt: skip
    run_trials(cfg, tmp_path / "old", progress=False)
    _as_schema_1(tmp_path / "old", drop=("cost.shaping_fade",))
    with pytest.raises(InputError, match="shaping_fade: folder has 'everywhere'"):
        run_trials(replace(cfg, n=2, plan=PlanSettings()), tmp_path / "old", progress=False)
    assert run_trials(replace(cfg, n=2), tmp_path / "old", progress=False)["trials"] == 2
    with pytest.raises(InputError, match="cost.shaping_fade is one of behind, everywhere"):
        CostConfig(shaping_fade="never")
    assert (
        main(
            [
                "trials",
                "--scenario",
                "tiny",
                "--n",
                "1",
                "--model",
                "no-motion",
                "--set",
                "cost.shaping_fade=never",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 2
    )


@pytest.mark.parametrize("name", ["w_keepout", "near_goal_m"])
def test_a_folder_from_before_a_cost_term_continues_only_without_it(name, tmp_path, capsys):
    """Records from before the keep-out term had none, and those from before the fade near the
    goal no fade: such a folder extends with the setting at 0 and is refused with another; the
    command line's value reaches the folder's cost, and a negative one is refused (exit 2)."""
    cfg = TrialsConfig("tiny", n=1, model="no-motion", max_steps=1,
                       plan=_plan(cost=CostConfig(**{name: 0.0})))  # fmt: skip
    run_trials(cfg, tmp_path / "old", progress=False)
    _as_schema_1(tmp_path / "old", drop=(f"cost.{name}",))
    with pytest.raises(InputError, match=f"cost.{name}: folder has 0.0, this run asks for 10.0"):
        run_trials(replace(cfg, n=2, plan=_plan(cost=CostConfig(**{name: 10.0}))),
                   tmp_path / "old", progress=False)  # fmt: skip
    assert run_trials(replace(cfg, n=2), tmp_path / "old", progress=False)["trials"] == 2
    args = ["trials", "--scenario", "tiny", "--n", "1", "--model", "no-motion", "--max-steps",
            "1", "--out", str(tmp_path / "cli")]  # fmt: skip
    assert main([*args, "--set", f"cost.{name}=7"]) == 0
    config = json.loads((tmp_path / "cli" / "config.json").read_text())
    assert config["plan"]["cost"][name] == 7.0
    assert main([*args, "--set", f"cost.{name}=-1"]) == 2
    assert f"cost.{name} must be a finite number >= 0, got -1.0" in capsys.readouterr().err


def test_a_folder_whose_scenario_file_changed_is_refused_and_kept(tmp_path):
    """A folder is matched to its scenario by name: when the file has changed since its trials
    ran, today's draw differs and the folder is refused (its log untouched, exit 2 from the
    command line); the same file extends it."""
    toml = tmp_path / "table.toml"
    toml.write_text((resources.files("scenarios") / "tiny.toml").read_text())
    cfg = TrialsConfig(str(toml), n=2, model="no-motion", max_steps=1)
    out = tmp_path / "set"
    run_trials(cfg, out, progress=False)
    assert run_trials(replace(cfg, n=3), out, progress=False)["trials"] == 3
    log = (out / "trials.jsonl").read_text()
    toml.write_text(toml.read_text().replace("region_m = [-0.06, 0.10, -0.08, 0.08]",
                                             "region_m = [-0.06, 0.10, -0.08, 0.0]"))  # fmt: skip
    with pytest.raises(InputError, match="no longer draws"):
        run_trials(replace(cfg, n=4), out, progress=False)
    assert (out / "trials.jsonl").read_text() == log
    assert main(["trials", "--scenario", str(toml), "--n", "4", "--model", "no-motion",
                 "--max-steps", "1", "--out", str(out)]) == 2  # fmt: skip
