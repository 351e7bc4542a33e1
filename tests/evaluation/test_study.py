import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from evaluation.study import (
    ACCURACY,
    StudyConfig,
    finding,
    measure_counts,
    parse_models,
    rank_correlations,
    run_study,
)
from planner.settings import resolve_settings
from scenarios import InputError
from se3net.train import TrainConfig, train


def test_rank_correlation_on_hand_made_models():
    rows = [
        {"ratio_to_no_motion": 0.1, "iou": 0.9, "success_tight": 0.9},
        {"ratio_to_no_motion": 0.3, "iou": None, "success_tight": 0.5},
        {"ratio_to_no_motion": 0.5, "iou": 0.8, "success_tight": 0.4},
        {"ratio_to_no_motion": 1.0, "iou": 0.7, "success_tight": 0.0},
    ]
    for r in rows:
        r.update(horizon_pos_err_cm=1.0, horizon_yaw_err_deg=None, mask_binariness=None)
    corr = rank_correlations(rows)
    # lower ratio, more success, in every pair: +1 after the sign for "lower is better"
    assert corr["ratio_to_no_motion"] == pytest.approx(1.0)
    # IoU over the three models that have one: ranks (3,2,1) against success (3,2,1) -> +1;
    # the model without masks is left out, not counted as zero
    assert corr["iou"] == pytest.approx(1.0)
    rows[2]["iou"] = 0.95  # the best IoU now has middling success: (2,3,1) vs (3,2,1)
    assert rank_correlations(rows)["iou"] == pytest.approx(0.5)
    assert corr["horizon_pos_err_cm"] is None  # no variation
    assert corr["horizon_yaw_err_deg"] is None and corr["mask_binariness"] is None
    words = finding(corr, 4)
    assert "predict closed-loop success best, tied" in words  # ratio and IoU tie at +1
    assert ACCURACY["iou"][0] in words and ACCURACY["ratio_to_no_motion"][0] in words
    assert "predicts closed-loop" in finding({**corr, "iou": 0.5}, 4)
    # a measure only some models have says over how many it ranks
    words = finding(corr, 4, covered=measure_counts(rows))
    assert f"{ACCURACY['iou'][0]} (the 3 with one) +1.00" in words
    assert f"{ACCURACY['ratio_to_no_motion'][0]} +1.00" in words


def test_model_labels_and_bad_settings():
    shipped = ["default", "single_box_64"]
    assert parse_models(["oracle", *shipped, "a=runs/x/best.pt", "runs/y/iter_000100.pt"]) == [
        ("oracle", "oracle"),
        ("default", "default"),
        ("single_box_64", "single_box_64"),
        ("a", "runs/x/best.pt"),
        ("y/iter_000100", "runs/y/iter_000100.pt"),
    ]
    with pytest.raises(ValueError, match="share a label"):
        StudyConfig("tiny", "d", models=("runs/a/best.pt", "other/a/best.pt"))
    with pytest.raises(ValueError, match="must be positive"):
        StudyConfig("tiny", "d", models=("oracle",), trials=0)
    with pytest.raises(ValueError, match="--max-steps must be positive, got 1, 10, 0"):
        StudyConfig("tiny", "d", models=("oracle",), trials=1, max_examples=10, max_steps=0)
    with pytest.raises(ValueError, match="rollout.contact_margin_m must be a distance"):
        resolve_settings(assignments=["rollout.contact_margin_m=-0.01"])
    with pytest.raises(ValueError, match="cost.shaping_fade is one of behind, everywhere"):
        resolve_settings(assignments=["cost.shaping_fade=never"])
    with pytest.raises(ValueError, match="horizon_s must be a time in seconds above 0, got 0"):
        resolve_settings(assignments=["optimiser.horizon_s=0"])


@pytest.fixture(scope="module")
def study_data(tmp_path_factory):
    """Tiny data with three held-out episodes, in one of which (59) the box is pushed."""
    from sim.dataset import DataConfig, generate

    root = tmp_path_factory.mktemp("study_data")
    generate(DataConfig("tiny", episodes=60, steps_per_episode=8, episodes_per_shard=20), root,
             progress=False)  # fmt: skip
    return root


def test_study_end_to_end_on_tiny(study_data, tmp_path):
    tiny_data = study_data
    run = tmp_path / "run"
    train(
        TrainConfig(data=str(tiny_data), out=str(run), iters=4, batch=4, eval_every=2,
                    val_examples=8, k=3, keep_every=2),
        progress=False,
    )  # fmt: skip
    models = ("oracle", "no-motion", f"early={run}/iter_000002.pt", f"late={run}/iter_000004.pt")
    plan = resolve_settings(assignments=["cost.shaping_fade=everywhere"])
    cfg = StudyConfig("tiny", str(tiny_data), models=models, trials=2, max_steps=3,
                      max_examples=40, plan=plan)  # fmt: skip
    rollout = plan.rollout
    result = run_study(cfg, tmp_path / "study")
    rows = {r["label"]: r for r in result["rows"]}
    assert list(rows) == ["oracle", "no-motion", "early", "late"]
    for label, r in rows.items():
        for key in (*ACCURACY, "flow_mse_cm2", "success_tight", "success_loose", "median_steps"):
            assert r[key] is not None, (label, key)
    assert rows["oracle"]["ratio_to_no_motion"] == 0 and rows["oracle"]["iou"] == 1
    assert rows["no-motion"]["ratio_to_no_motion"] == pytest.approx(1.0)
    assert rows["no-motion"]["horizon_pos_err_cm"] > 0.3  # the windows are ones where it moves
    table = (tmp_path / "study" / "study.md").read_text().splitlines()
    body = [line for line in table if line.startswith("| ") and not line.startswith("| model")]
    assert [line.split("|")[1].strip() for line in body] == list(rows)
    assert all(cell.strip() for line in body for cell in line.split("|")[1:-1])
    saved = json.loads((tmp_path / "study" / "study.json").read_text())
    assert set(saved["rank_correlation_with_success"]) == set(ACCURACY) and saved["finding"]
    assert set(saved["rank_correlation_learned_only"]) == set(ACCURACY)
    assert (tmp_path / "study" / "study.png").read_bytes()[:4] == b"\x89PNG"
    trials = json.loads((tmp_path / "study" / "trials" / "late" / "config.json").read_text())
    assert trials["plan"]["rollout"] == {
        "feedback": rollout.feedback,
        "contact_margin_m": rollout.contact_margin_m,
    }
    assert trials["plan"]["cost"]["shaping_fade"] == "everywhere"  # the study's, not the default
    assert trials["plan"]["optimiser"]["horizon_s"] == plan.optimiser.horizon_s == 0.45
    # a second run reuses the cached accuracy and the finished trials
    cache = tmp_path / "study" / "accuracy" / "late.json"
    cached = json.loads(cache.read_text())
    assert cached["rolled"] == {
        "feedback": rollout.feedback,
        "contact_margin_m": rollout.contact_margin_m,
        "horizon": 3,
    }
    cache.write_text(json.dumps({**cached, "horizon_pos_err_cm": 99.0}))
    again = run_study(cfg, tmp_path / "study")
    assert [r["success_tight"] for r in again["rows"]] == [
        r["success_tight"] for r in rows.values()
    ]
    assert again["rows"][-1]["horizon_pos_err_cm"] == 99.0 and "rolled" not in again["rows"][-1]
    # a cache rolled otherwise (from before the planner's options: the grid, no gate) is not
    cache.write_text(json.dumps({k: v for k, v in cached.items() if k != "rolled"}
                                | {"horizon_pos_err_cm": 99.0}))  # fmt: skip
    measured = run_study(cfg, tmp_path / "study")["rows"][-1]["horizon_pos_err_cm"]
    assert measured == pytest.approx(rows["late"]["horizon_pos_err_cm"])
    # nor is one from before the horizon was recorded (rolled 4 steps, not the study's 3)
    rolled = {k: v for k, v in cached["rolled"].items() if k != "horizon"}
    cache.write_text(json.dumps({**cached, "rolled": rolled, "horizon_pos_err_cm": 99.0}))
    measured = run_study(cfg, tmp_path / "study")["rows"][-1]["horizon_pos_err_cm"]
    assert measured == pytest.approx(rows["late"]["horizon_pos_err_cm"])
    # nor one of other weights or data (the label names a path, whose file may change)
    early = json.loads((tmp_path / "study" / "accuracy" / "early.json").read_text())
    # the data by its manifest's hash: a folder made again at the same path is other data
    from se3net.checkpoint import manifest_hash
    from sim.datastore import read_manifest

    data_id = manifest_hash(read_manifest(tiny_data))
    assert cached["measured"]["data"] == data_id and cached["measured"]["max_examples"] == 40
    assert len({early["measured"]["model_sha256"], cached["measured"]["model_sha256"]}) == 2
    for other in ({"data": "elsewhere"}, {"model_sha256": early["measured"]["model_sha256"]}):
        stale = {**cached, "measured": {**cached["measured"], **other}, "horizon_pos_err_cm": 99.0}
        cache.write_text(json.dumps(stale))
        measured = run_study(cfg, tmp_path / "study")["rows"][-1]["horizon_pos_err_cm"]
        assert measured == pytest.approx(rows["late"]["horizon_pos_err_cm"])
    with pytest.raises(InputError, match="name one folder"):
        replace(cfg, models=("a/b=x.pt", "a_b=y.pt"))


class _AlongThePush:
    """A stand-in model that moves the object exactly as the pusher is commanded: no push
    deflects it."""

    name, differentiable = "toy", True

    def __init__(self, dt):
        self.dt = dt

    def rollout(self, state, actions, *, clouds=False):
        from planner.dynamics import Rollout, integrate_pusher

        xy = state.object_pose[:2].to(actions) + self.dt * torch.cumsum(actions, 1)
        yaw = state.object_pose[2].to(actions).expand(xy.shape[:2])
        return Rollout(
            torch.cat([xy, yaw[..., None]], -1), integrate_pusher(state, actions, self.dt)
        )


def test_push_deflection_of_a_model_that_moves_the_object_the_pusher_s_way(study_data):
    """A model that moves the object along the pusher's commanded velocity predicts no
    deflection, so its direction error is the true deflection, bin by bin; every window
    counted was a push toward the object's side of the pusher."""
    from evaluation.deflection import OFF_CENTRE_BINS_DEG, push_deflection
    from scenarios import load_scenario

    dt = load_scenario("tiny").action.dt_control_s
    (rows,) = push_deflection([_AlongThePush(dt)], study_data)
    assert rows and sum(r["windows"] for r in rows) >= 3
    for r in rows:
        assert tuple(r["off_centre_deg"]) in OFF_CENTRE_BINS_DEG and r["shape"] == "box"
        assert r["predicted_deflection_deg"] < 0.1
        assert abs(r["direction_error_deg"] - r["true_deflection_deg"]) < 0.1
        assert r["true_deflection_deg"] > 0.1  # a real box turns away from any push a little
        assert r["left_behind"] is None  # no clouds to measure it on
    # every episode of a dataset held out as a whole: more windows than its test split
    (every,) = push_deflection([_AlongThePush(dt)], study_data, split="all")
    assert sum(r["windows"] for r in every) > sum(r["windows"] for r in rows)


def test_left_behind_counts_the_points_a_torn_prediction_does_not_carry(study_data):
    """A cloud whose object moves as one body leaves none of it behind, whether by its true
    motion or by a rigid step too short (a short step is not a tear); one that moves only the
    object's points on one side of its centre leaves the other side; the observed cloud itself
    (nothing moved) has no step to tear."""
    from evaluation.deflection import left_behind
    from evaluation.study import _moving_windows, _window_states
    from planner.dynamics import to_world
    from se3net.data import PushDataset

    ds = PushDataset(study_data, split="all", horizon=1)
    pick, start, end = _moving_windows(ds, study_data, 0, 4, "all")
    state, _, _ = next(_window_states(ds, pick, start, 0))
    start, end = start[0], end[0]
    assert np.hypot(*(end - start)[:2]) > 1e-3  # the object moves
    T = state.T_world_cam
    seen = (state.object_mask & state.valid).flatten()
    world = to_world(T, state.points.flatten(1)[:, seen].T).double()

    def rigidly(share: float) -> torch.Tensor:
        """The object's points moved by ``share`` of its true step (turn and slide), camera
        frame (3,N)."""
        turn = share * (end[2] - start[2])
        c, s = np.cos(turn), np.sin(turn)
        xy = (world[:, :2] - torch.from_numpy(start[:2])) @ torch.tensor([[c, s], [-s, c]])
        to = start[:2] + share * (end[:2] - start[:2])
        moved = torch.cat([xy + torch.from_numpy(to), world[:, 2:]], 1)
        return ((moved - T[:3, 3].double()) @ T[:3, :3].double()).float().T  # p_cam

    def cloud(points: torch.Tensor) -> torch.Tensor:
        out = state.points.flatten(1).clone()
        out[:, seen] = points
        return out.view_as(state.points)

    assert left_behind(state, cloud(rigidly(1.0))) == 0.0
    assert left_behind(state, cloud(rigidly(0.3))) == 0.0  # short, but whole
    assert np.isnan(left_behind(state, state.points))
    one_side = world[:, 0] > float(start[0])  # the object's points beyond its centre in x
    torn = torch.where(one_side[None], rigidly(1.0), state.points.flatten(1)[:, seen])
    share = left_behind(state, cloud(torn))
    assert share == pytest.approx(1 - one_side.float().mean().item())
    assert 0.2 < share < 0.8


def test_deflection_refuses_a_backend_without_a_model(study_data, capsys):
    from se3push.cli import main

    assert main(["deflection", "--data", str(study_data), "--models", "oracle"]) == 2
    assert "oracle has no deflection to measure" in capsys.readouterr().err
    assert main(["deflection", "--data", str(study_data), "--models", "default",
                 "--max-windows", "0"]) == 2  # fmt: skip
    assert "--max-windows must be positive, got 0" in capsys.readouterr().err


def test_deflection_on_all_episodes_refuses_a_model_trained_on_them(study_data, tmp_path, capsys):
    from se3push.cli import main

    run = tmp_path / "run"
    train(TrainConfig(data=str(study_data), out=str(run), iters=2, batch=4, eval_every=2,
                      val_examples=8, k=3), progress=False)  # fmt: skip
    args = ["deflection", "--data", str(study_data), "--models", str(run / "best.pt")]
    assert main([*args, "--split", "all", "--json", str(tmp_path / "d.json")]) == 2
    assert "was trained on" in capsys.readouterr().err
    assert not (tmp_path / "d.json").exists()


def test_push_deflection_leaves_predicted_stillness_out_of_the_angles(study_data):
    """A model that predicts no motion has no direction to compare: every window counts as
    predicted still, the angles are None (not the 90 degrees a zero vector would give), and
    the length ratio is about 0."""
    from evaluation.deflection import push_deflection
    from planner.dynamics import make_dynamics
    from scenarios import load_scenario

    (rows,) = push_deflection([make_dynamics("no-motion", load_scenario("tiny"))], study_data)
    assert rows
    for r in rows:
        assert r["predicted_still"] == r["windows"]
        assert r["predicted_deflection_deg"] is None and r["direction_error_deg"] is None
        assert r["length_ratio"] < 1e-3
