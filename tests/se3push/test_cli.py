import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import torch

import scenarios
from scenarios import InputError, ScenarioError
from se3net.checkpoint import CheckpointError
from se3push.cli import main
from se3push.plan_push import main as plan_push_main
from sim import ActionError
from sim.shards import DataError

ROOT = Path(__file__).resolve().parents[2]


def test_scenarios_lists_each_with_a_description(capsys):
    assert main(["scenarios"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = {line.split()[0] for line in lines}
    assert {"single_box", "multi_object", "tiny"} <= names
    assert all(len(line.split(maxsplit=1)[1]) > 10 for line in lines)


def test_a_reader_that_stops_early_ends_the_command_quietly():
    # the read end closed before the command prints: its first line meets a broken pipe
    proc = subprocess.Popen([sys.executable, "-m", "se3push.cli", "scenarios"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141  # as a shell reports a process that SIGPIPE ended
    assert err == ""  # no traceback, not even from the flush at exit


def test_render_writes_a_png_showing_object_flow(tmp_path, capsys):
    out = tmp_path / "scene.png"
    assert main(["render", "--scenario", "tiny", "--seed", "3", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = capsys.readouterr().out
    flow_mm = float(text.split("max flow ")[1].split(" mm")[0])
    assert flow_mm > 1.0  # the push reached the object and the flow shows it


@pytest.mark.parametrize(("args", "message"), [
    (["--seed", "-3", "--out", "{tmp}/a.png"], "--seed must be an integer in [0, 2**63), got -3"),
    (["--out", "{tmp}"], "is a folder; give the picture's file name"),
    (["--out", "{tmp}/a.txt"], "a.txt: a picture is one of "),
])  # fmt: skip
def test_render_bad_input_is_one_line_and_exit_code_2(args, message, tmp_path, capsys):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    assert main(["render", "--scenario", "tiny", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_unknown_scenario_is_exit_code_2_with_the_known_ones(tmp_path, capsys):
    assert main(["render", "--scenario", "nope", "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "unknown scenario 'nope'" in err and "single_box" in err


def test_bench_world_writes_the_named_figures(tmp_path):
    path = tmp_path / "bench.json"
    assert main(["bench", "world", "--repeats", "1", "--json", str(path)]) == 0
    figures = json.loads(path.read_text())
    assert set(figures) == {"camera_fps_64x64", "camera_fps_240x320", "control_steps_per_s"}
    assert figures["camera_fps_64x64"] > figures["camera_fps_240x320"] > 0


def test_wheel_carries_the_scenario_files_and_the_default_model(tmp_path):
    pytest.importorskip("setuptools")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp_path), str(ROOT)],
        check=True, capture_output=True,
    )  # fmt: skip
    (wheel,) = tmp_path.glob("se3push-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for stem in ("single_box", "multi_object", "tiny"):
        assert f"scenarios/{stem}.toml" in names
    assert "se3net/weights/default.pt" in names  # the shipped model


def test_data_generates_and_inspects(tmp_path, capsys):
    out = tmp_path / "data"
    args = [
        "data",
        "--scenario",
        "tiny",
        "--episodes",
        "3",
        "--steps-per-episode",
        "4",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    assert "3 episodes" in capsys.readouterr().out
    assert main(["data", "--inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "no-motion MSE" in text and "object moves" in text and "policy mixture" in text
    assert (out / "inspect.png").read_bytes()[:4] == b"\x89PNG"
    # the same command again finds everything done; another seed is refused
    assert main(args) == 0
    assert main([*args, "--seed", "5"]) == 2
    assert "holds a different dataset" in capsys.readouterr().err


def test_data_bad_input_is_exit_code_2(tmp_path, capsys):
    assert main(["data", "--scenario", "tiny", "--out", str(tmp_path / "d")]) == 2
    assert "--episodes is required" in capsys.readouterr().err
    assert main(["data", "--inspect", str(tmp_path)]) == 2
    assert "not a dataset folder" in capsys.readouterr().err
    assert (
        main(
            [
                "data",
                "--scenario",
                "tiny",
                "--episodes",
                "2",
                "--workers",
                "0",
                "--out",
                str(tmp_path / "w"),
            ]
        )
        == 2
    )
    assert "--workers must be at least 1" in capsys.readouterr().err


def test_bench_data_writes_the_named_figures(tmp_path):
    path = tmp_path / "bench.json"
    assert main(["bench", "data", "--repeats", "1", "--json", str(path)]) == 0
    figures = json.loads(path.read_text())
    assert set(figures) == {
        "examples_per_s_1_worker",
        "examples_per_s_2_workers",
        "bytes_per_example",
    }
    assert all(v > 0 for v in figures.values())


def test_train_and_eval_commands(tiny_data, tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--data", str(tiny_data), "--out", str(run), "--iters", "4", "--batch", "4",
            "--eval-every", "2", "--k", "3"]  # fmt: skip
    assert main(args) == 0
    assert "ratio to no-motion" in capsys.readouterr().out
    assert main(args) == 2  # the run exists: resume or choose another folder
    assert "--resume" in capsys.readouterr().err
    assert main([*args, "--resume"]) == 0
    out = tmp_path / "eval"
    assert (
        main(
            [
                "eval",
                "--data",
                str(tiny_data),
                "--checkpoints",
                str(run / "best.pt"),
                "--out",
                str(out),
                "--max-examples",
                "20",
            ]
        )
        == 0
    )
    assert "| ratio to no-motion |" in capsys.readouterr().out
    assert json.loads((out / "eval.json").read_text())["run"]["variant"] == "se3net"
    # every episode is for a held-out dataset, not the run's own training data
    every = tmp_path / "eval_all"
    assert main(["eval", "--data", str(tiny_data), "--checkpoints", str(run / "best.pt"),
                 "--out", str(every), "--split", "all"]) == 2  # fmt: skip
    assert "was trained on" in capsys.readouterr().err
    assert not (every / "eval.json").exists()


def test_a_pose_model_trains_plans_and_is_refused_where_clouds_are_needed(tiny_data, tmp_path,
                                                                           capsys):  # fmt: skip
    run = tmp_path / "pose"
    args = ["train", "--variant", "pose", "--data", str(tiny_data), "--out", str(run),
            "--iters", "30", "--batch", "16"]  # fmt: skip
    assert main(args) == 0
    assert "validation position error after 1 and 8 steps" in capsys.readouterr().out
    assert main(args) == 2  # no resume: another folder
    assert "holds a run already" in capsys.readouterr().err
    assert main([*args[:-4], "--out", str(tmp_path / "p2"), "--stride", "2", "--init", "x"]) == 2
    assert "--stride, --init: not for --variant pose" in capsys.readouterr().err
    ckpt = str(run / "best.pt")
    assert main(["eval", "--data", str(tiny_data), "--checkpoints", ckpt,
                 "--out", str(tmp_path / "e")]) == 2  # fmt: skip
    assert "is a pose model" in capsys.readouterr().err
    trials = tmp_path / "trials"
    assert main(["trials", "--scenario", "tiny", "--n", "1", "--model", ckpt, "--max-steps", "3",
                 "--out", str(trials)]) == 0  # fmt: skip
    record = json.loads((trials / "trials.jsonl").read_text().splitlines()[0])
    assert record["steps"] == 3  # a replan each step, none refused
    assert json.loads((trials / "config.json").read_text())["model"] == ckpt


def test_a_seed_numpy_or_torch_cannot_take_is_refused_before_anything_runs(tiny_data, tmp_path,
                                                                           capsys):  # fmt: skip
    runs = [
        ["data", "--scenario", "tiny", "--episodes", "1", "--out", str(tmp_path / "d")],
        ["train", "--data", str(tiny_data), "--out", str(tmp_path / "r")],
        ["trials", "--scenario", "tiny", "--n", "1", "--out", str(tmp_path / "t")],
    ]
    for args in runs:
        assert main([*args, "--seed", "-1"]) == 2, args
        assert "--seed must be an integer in [0, 2**63), got -1" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_train_and_eval_bad_input_is_exit_code_2(tiny_data, tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "r")]) == 2
    assert "not a dataset folder" in capsys.readouterr().err
    assert (
        main(["train", "--data", str(tiny_data), "--out", str(tmp_path / "r"), "--variant", "huge"])
        == 2
    )
    assert "unknown variant 'huge'" in capsys.readouterr().err
    args = [
        "eval",
        "--data",
        str(tiny_data),
        "--checkpoints",
        str(tmp_path / "none.pt"),
        "--out",
        str(tmp_path / "e"),
    ]
    assert main(args) == 2
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, message",
    [
        (["train", "--init", "nowhere.pt"], "nowhere.pt does not exist"),
        (["study", "--models", "a=x.pt", "a=y.pt"], "share a label"),
        (["study", "--models", "oracle", "--trials", "0"], "must be positive"),
        (["improve", "--model", "default", "--rounds", "0"], "--rounds must be positive"),
        (["improve", "--model", "default", "--action-noise", "2"], "action noise must be in"),
        (
            ["improve", "--model", "default", "--visited-fraction", "1"],
            "--visited-fraction must be in [0, 1), got 1.0",
        ),
        (["train", "--later-fraction", "0.5"], "after the first 1, and there are 1: give more"),
        (["train", "--noise", "loud"], "--noise must be one of none, depth-scaled, depth, assoc-9"),
        (["train", "--batch", "0"], "--batch must be positive, got 0"),
        (["improve", "--model", "pose"], "is a pose model"),  # before round 0's trials
        (["study", "--models", "oracle", "pose"], "is a pose model"),  # before the oracle's
        (["train", "--variant", "pose", "--batch", "0"], "--batch must be positive, got 0"),
        (["train", "--variant", "pose", "--seed", "-1"], "--seed must be an integer in"),
        (["improve", "--model", "default"], "does not fit scenario 'tiny'"),
    ],
)
def test_study_improve_and_rollout_bad_input_is_exit_code_2(
    args, message, tiny_data, tmp_path, capsys
):
    base = {"train": ["--out", str(tmp_path / "r")], "study": ["--out", str(tmp_path / "s")],
            "improve": ["--out", str(tmp_path / "i")]}[args[0]]  # fmt: skip
    assert main([*args, "--data", str(tiny_data), *base, *(
        ["--scenario", "tiny"] if args[0] != "train" else [])]) == 2  # fmt: skip
    assert message in capsys.readouterr().err
    assert not (tmp_path / "i").exists()  # improve refuses before writing anything


@pytest.mark.parametrize("command", ["trials", "plan-push", "eval"])
def test_an_unknown_feedback_is_exit_code_2_naming_the_known_ones(
    command, tiny_data, tmp_path, capsys
):
    args = {
        "trials": ["trials", "--scenario", "single_box", "--n", "1", "--out", str(tmp_path / "t")],
        "eval": ["eval", "--data", str(tiny_data), "--checkpoints", "default",
                 "--out", str(tmp_path / "e")],
    }.get(command, [])  # fmt: skip
    planning = command in ("trials", "plan-push")  # the planner's rollout is a setting
    bad = ["--set", "rollout.feedback=mirrored"] if planning else ["--feedback", "mirrored"]
    if command == "plan-push":
        code = plan_push_main(["--goal", "0.16", "0", "90", *bad])
    else:
        code = main([*args, *bad])
    assert code == 2
    name = "rollout.feedback" if planning else "--feedback"
    assert f"{name} must be one of grid, rendered, got 'mirrored'" in capsys.readouterr().err
    assert not (tmp_path / "t" / "trials.jsonl").exists()  # refused before any trial ran


@pytest.mark.parametrize("margin", ["-0.01", "nan"])
def test_a_bad_contact_margin_is_exit_code_2(margin, tmp_path, capsys):
    bad = ["--set", f"rollout.contact_margin_m={margin}"]
    code = main(["trials", "--scenario", "single_box", "--n", "1", *bad,
                 "--out", str(tmp_path / "t")])  # fmt: skip
    assert code == 2
    assert "rollout.contact_margin_m must be a distance >= 0 in metres" in capsys.readouterr().err
    assert plan_push_main(["--goal", "0.16", "0", "90", *bad]) == 2
    assert not (tmp_path / "t" / "trials.jsonl").exists()


def test_the_contact_margin_is_a_distance_or_off(tmp_path, capsys):
    base = ["trials", "--scenario", "tiny", "--n", "1", "--max-steps", "1", "--model", "no-motion"]
    margin = "rollout.contact_margin_m"
    assert main([*base, "--set", f"{margin}=1cm", "--out", str(tmp_path / "bad")]) == 2
    assert f"setting {margin} must be off or float, got '1cm'" in capsys.readouterr().err
    for value, recorded in (("off", None), ("0.02", 0.02)):
        assert main([*base, "--set", f"{margin}={value}", "--out", str(tmp_path / value)]) == 0
        config = json.loads((tmp_path / value / "config.json").read_text())
        assert config["plan"]["rollout"]["contact_margin_m"] == recorded


def test_an_unexpected_error_inside_a_command_shows_its_traceback(monkeypatch):
    def boom():
        raise ValueError("boom")

    monkeypatch.setattr(scenarios, "list_scenarios", boom)
    with pytest.raises(ValueError, match="boom"):  # a bug, not bad input: no exit code 2
        main(["scenarios"])


def test_refused_input_of_every_package_is_an_input_error():
    for error in (ScenarioError, ActionError, DataError, CheckpointError):
        assert issubclass(error, InputError), error


@pytest.mark.parametrize(
    "error", [InputError, ScenarioError, ActionError, DataError, CheckpointError, FileNotFoundError]
)
def test_refused_input_is_one_line_and_exit_code_2(error, monkeypatch, capsys):
    def refuse():
        raise error("what was wrong; what to do")

    monkeypatch.setattr(scenarios, "list_scenarios", refuse)
    assert main(["scenarios"]) == 2
    assert capsys.readouterr().err == "error: what was wrong; what to do\n"


@pytest.mark.parametrize(
    "device, message",
    [
        ("cuda", "CUDA is not available on this machine"),
        ("cuda:9", "CUDA is not available on this machine"),
        ("gpu7", "unknown device 'gpu7'"),
        ("nonsense", "unknown device 'nonsense'"),
    ],
)
def test_a_device_this_machine_lacks_is_exit_code_2(
    device, message, tiny_data, tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    run = tmp_path / "run"
    args = ["train", "--data", str(tiny_data), "--out", str(run), "--device", device]
    assert main(args) == 2
    assert message in capsys.readouterr().err
    assert not run.exists()
    assert plan_push_main(["--goal", "0.1", "0", "0", "--device", device]) == 2
    assert message in capsys.readouterr().err
    assert main(["bench", "planner", "--repeats", "1", "--device", device]) == 2
    assert message in capsys.readouterr().err


def test_bench_refuses_bad_settings_before_timing_anything(tmp_path, capsys):
    assert main(["bench", "world", "--repeats", "0"]) == 2
    assert "--repeats must be at least 1, got 0" in capsys.readouterr().err
    assert main(["bench", "world", "--repeats", "1", "--json", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    se3 = "default"  # an SE3-Net, not a flow net
    assert main(["bench", "planner", "--repeats", "1", "--flow-model", se3]) == 2
    assert "--flow-model default is not a flow net" in capsys.readouterr().err


def test_bench_planner_writes_every_pair(tmp_path):
    path = tmp_path / "bench.json"
    assert main(["bench", "planner", "--repeats", "1", "--json", str(path)]) == 0
    figures = json.loads(path.read_text())
    assert figures["default"] == "cem/se3net"
    times = figures["replan_ms_median"]
    for planner in ("cem", "mppi", "grad", "sqp"):
        for backend in ("se3net", "oracle", "no-motion"):
            assert f"{planner}/{backend}" in times
    assert times["grad/oracle"] is None and times["cem/oracle"] > times["cem/no-motion"] > 0
    assert figures["se3net_rollout_candidate_steps_per_s"] > 0
    planned = figures["planner_default"]
    assert planned["replan_ms_median"] > 0 and planned["replan_ms_two_processes"] > 0
