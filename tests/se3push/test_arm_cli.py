"""The arm scenario on the command line: data and pictures work; every closed-loop command
refuses it (its actions are joint velocities, not pushes) with one line and exit code 2."""

import pytest

from se3push.cli import main
from se3push.plan_push import main as plan_push_main

REFUSAL = "scenario 'arm' has joint-velocity controls, not pusher actions"


@pytest.mark.parametrize(
    "argv",
    [
        ["plan-push", "--goal", "0.1", "0.0", "0"],
        ["trials", "--n", "1", "--out", "{out}"],
        ["improve", "--model", "default", "--data", "{out}/data", "--out", "{out}"],
        ["study", "--data", "{out}/data", "--models", "oracle", "--out", "{out}"],
    ],
    ids=lambda argv: argv[0],
)
def test_closed_loop_commands_refuse_the_arm_scenario(tmp_path, capsys, argv):
    out = tmp_path / "out"
    args = [a.format(out=out) for a in argv] + ["--scenario", "arm"]
    code = plan_push_main(args[1:]) if args[0] == "plan-push" else main(args)
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert REFUSAL in err and len(err.splitlines()) == 1
    assert not out.exists()  # refused before anything was written


def test_data_and_render_of_the_arm(tmp_path, capsys):
    data = tmp_path / "data"
    argv = ["data", "--scenario", "arm", "--episodes", "2", "--steps-per-episode", "3"]
    assert main([*argv, "--out", str(data)]) == 0
    out = capsys.readouterr().out
    assert "6 examples" in out and "moving points per example" in out
    assert main(["data", "--inspect", str(data)]) == 0
    text = capsys.readouterr().out
    assert "yaw_vel_rad_s, pitch1_vel_rad_s" in text and "scenes of 1-4 joints" in text
    png = tmp_path / "arm.png"
    assert main(["render", "--scenario", "arm", "--seed", "1", "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    pixels = capsys.readouterr().out.split("pixels per part: ")[1]
    counts = dict(item.rsplit(" ", 1) for item in pixels.strip().split(", "))
    for link in ("pusher", "arm base", "upper arm", "forearm"):
        assert int(counts[link]) >= 10, link
