import base64
import json
import math
import re
import shutil

import numpy as np
import pytest

from integrations.viz import MeshcatVisualiser
from planner.loop import PushConfig, run_push
from scenarios import load_scenario
from se3push.plan_push import main as plan_push_main
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
        "/meshcat/predicted/2",  # the last of the horizon's 3 steps
    } <= set(tracks)
    for path, clip_tracks in tracks.items():
        for track in clip_tracks:
            assert len(track["keys"]) == result.steps, path


def test_a_start_that_fails_leaves_no_meshcat_server_behind(monkeypatch):
    import meshcat

    started = []

    class Recorded(meshcat.Visualizer):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            started.append(self)

    def broken(self, obs, model):
        raise RuntimeError("the cloud could not be drawn")

    monkeypatch.setattr(meshcat, "Visualizer", Recorded)
    monkeypatch.setattr(MeshcatVisualiser, "_cloud", broken)
    world = PushWorld(load_scenario("tiny"))
    obs = world.reset(0)
    with pytest.raises(RuntimeError, match="could not be drawn"):
        MeshcatVisualiser().start(world, obs, obs.object_poses[0])
    (vis,) = started
    assert vis.window.server_proc.poll() is not None  # the server process has ended


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
    # with --json, stdout is the result's JSON alone (meshcat's URL and the file on stderr)
    assert plan_push_main([*args, "--json"]) == 1
    said = capsys.readouterr()
    assert json.loads(said.out)["steps"] == 2
    assert f"wrote {out} (2 frames)" in said.err
    # a folder is refused before the push, not after it
    args[-1] = str(tmp_path)
    assert plan_push_main(args) == 2
    err = capsys.readouterr()
    assert "is a folder; give the HTML file's path" in err.err and "step" not in err.out


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


def _screenshot(html, png) -> None:
    """``html`` rendered by headless Chromium (WebGL in software) into ``png``, 800x600."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as profile:
        subprocess.run(
            ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--no-first-run", f"--user-data-dir={profile}", "--virtual-time-budget=8000",
             "--window-size=800,600", f"--screenshot={png}", f"file://{html}"],
            check=True, capture_output=True, timeout=120,
        )  # fmt: skip


def _drawn(png):
    """Masks of the pixels that show the table (tan #C8B89A, shaded) and the objects (orange
    #DD7733)."""
    import matplotlib.image as mi

    im = (mi.imread(png)[..., :3] * 255).astype(int)
    r, g, b = im[..., 0], im[..., 1], im[..., 2]
    table = (r > g) & (g > b) & (r - b > 25) & (r - b < 90) & (r > 120)
    obj = (r - g > 60) & (r - b > 110)
    return table, obj


@pytest.mark.skipif(shutil.which("chromium") is None, reason="needs Debian's chromium")
def test_a_recording_draws_the_table_and_the_object_in_a_real_browser(tmp_path):
    """A --record file loaded in headless Chromium: the table fills the view (the camera
    frames it) and the pushed object is drawn on it."""
    html, png = tmp_path / "run.html", tmp_path / "run.png"
    assert plan_push_main(["--goal", "0.16", "0.0", "90", "--model", "oracle", "--max-steps",
                           "1", "--record", str(html)]) in (0, 1)  # fmt: skip
    _screenshot(html, png)
    table, obj = _drawn(png)
    rows, cols = map(lambda a: a.nonzero()[0], (table.any(1), table.any(0)))
    height, width = table.shape
    assert (np.ptp(cols) + 1) / width > 0.45 and (np.ptp(rows) + 1) / height > 0.45, "too small"
    assert obj.sum() > 400  # the box, seen from about 0.6 m: over a thousand pixels
    # the object sits on the table: its pixels lie within the table's extent
    oy, ox = obj.nonzero()
    assert rows.min() <= np.median(oy) <= rows.max() and cols.min() <= np.median(ox) <= cols.max()


def test_a_terminated_plan_push_leaves_no_meshcat_server_behind(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    obs = PushWorld(load_scenario("tiny")).reset(0)
    x, y, yaw = obs.object_poses[0]
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys; from se3push.plan_push import main; sys.exit(main())",
         "--goal", str(x), str(y + 0.05),
         str(math.degrees(yaw)), "--scenario", "tiny", "--model", "oracle", "--max-steps", "60",
         "--record", str(tmp_path / "push.html")],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        while not proc.stdout.readline().startswith("step"):  # the server is up: it steps
            assert proc.poll() is None
        children = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()
                    and _parent(p) == proc.pid]  # fmt: skip
        assert children  # meshcat's server
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    finally:
        proc.kill()
    for pid in children:  # ended, not orphaned to init
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            continue
        assert _parent(Path(f"/proc/{pid}")) != 1, f"meshcat's server {pid} outlived plan-push"


def _parent(proc_dir) -> int | None:
    try:
        for line in (proc_dir / "status").read_text().splitlines():
            if line.startswith("PPid:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None
