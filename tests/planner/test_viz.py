import base64
import math
import re

import pytest

from planner.loop import PushConfig, run_push
from planner.viz import MeshcatVisualiser
from scenarios import load_scenario
from se3push.cli import plan_push_main
from sim import PushWorld

pytestmark = pytest.mark.viz


def _rows(flat) -> list:
    """meshcat's packed float arrays as rows of three."""
    import numpy as np

    values = np.frombuffer(flat.data, dtype=np.float32) if hasattr(flat, "data") else flat
    return np.asarray(values).reshape(-1, 3).tolist()


def _commands(html: str) -> list[dict]:
    import umsgpack  # meshcat's own dependency

    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def test_recorded_html_holds_one_animation_frame_per_step(tmp_path):
    obs = PushWorld(load_scenario("tiny")).reset(0)
    x, y, yaw = obs.object_poses[0]
    out = tmp_path / "run.html"
    viz = MeshcatVisualiser(record=out)
    result = run_push(
        PushConfig(
            goal=(float(x + 0.04), float(y), float(yaw)),
            scenario="tiny",
            model="oracle",
            max_steps=3,
        ),
        viz=viz,
    )
    html = out.read_text()
    assert html.lstrip().startswith("<!DOCTYPE html>") and viz.frames == result.steps == 3
    cmds = _commands(html)
    objects = {c["path"] for c in cmds if c["type"] == "set_object"}
    expected = {"/meshcat/table", "/meshcat/pusher", "/meshcat/cloud", "/meshcat/goal/shape/0"}
    assert expected <= objects
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    tracks = {a["path"]: a["clip"]["tracks"] for a in anim["animations"]}
    assert {
        "/meshcat/objects/0",
        "/meshcat/pusher",
        "/meshcat/predicted/0",
        "/meshcat/predicted/3",
    } <= set(tracks)
    for path, clip_tracks in tracks.items():
        for track in clip_tracks:
            assert len(track["keys"]) == result.steps, path


def test_plan_push_record_flag(tmp_path, capsys):
    obs = PushWorld(load_scenario("tiny")).reset(0)
    x, y, yaw = obs.object_poses[0]
    out = tmp_path / "push.html"
    goal = [str(x), str(y + 0.03), str(math.degrees(yaw))]
    args = ["--goal", *goal, "--scenario", "tiny", "--model", "no-motion", "--max-steps", "2"]
    args += ["--record", str(out)]
    assert plan_push_main(args) == 1
    assert f"wrote {out} (2 frames)" in capsys.readouterr().out
    assert out.stat().st_size > 100_000


def test_the_shipped_planning_resolution_model_colours_the_cloud_by_its_masks(tmp_path):
    """The default network sees every other pixel: the recording still shows the full cloud,
    each point coloured by the mask of the network pixel it falls in."""
    scenario = load_scenario("single_box")
    obs = PushWorld(scenario).reset(0)
    x, y, yaw = obs.object_poses[0]
    out = tmp_path / "default.html"
    viz = MeshcatVisualiser(record=out)
    cfg = PushConfig(goal=(float(x - 0.05), float(y), float(yaw)), max_steps=1)
    run_push(cfg, viz=viz)
    (cloud,) = [c for c in _commands(out.read_text()) if c.get("path") == "/meshcat/cloud"]
    attrs = cloud["object"]["geometries"][0]["data"]["attributes"]
    n = obs.valid.sum()
    assert len(_rows(attrs["position"]["array"])) == n  # every camera point, not every other
    assert len(set(map(tuple, _rows(attrs["color"]["array"])))) >= 2  # coloured by mask
