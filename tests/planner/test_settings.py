"""The one settings object: TOML round trip, strict parsing, presets, the command line."""

import dataclasses

import pytest

from planner import CostConfig, PlannerConfig, PlanSettings, RolloutConfig
from planner.presets import PRESETS
from planner.settings import (
    read_toml,
    resolve_settings,
    settings_dict,
    settings_from_dict,
    settings_toml,
)
from scenarios import InputError
from se3push.cli import main
from se3push.plan_push import main as plan_push_main


@pytest.mark.parametrize("name", list(PRESETS))
def test_a_toml_round_trip_gives_the_same_settings(name, tmp_path):
    path = tmp_path / "plan.toml"
    path.write_text(settings_toml(PRESETS[name]))
    assert settings_from_dict(read_toml(path)) == PRESETS[name]


def test_settings_that_are_not_the_defaults_survive_the_round_trip(tmp_path):
    odd = PlanSettings(
        planner="mppi",
        optimiser=PlannerConfig(horizon_s=1.05, warm_std=None, temperature=0.125),
        cost=CostConfig(shaping_fade="everywhere", w_keepout=2.5),
        rollout=RolloutConfig(feedback="grid", contact_margin_m=None),
    )
    path = tmp_path / "odd.toml"
    path.write_text(settings_toml(odd))
    assert resolve_settings(config=path) == odd


def test_later_sources_override_earlier_ones(tmp_path):
    path = tmp_path / "plan.toml"
    path.write_text("[optimiser]\nhorizon_s = 0.75\nsamples = 16\n")
    s = resolve_settings(
        preset="fade_behind", config=path, assignments=["optimiser.samples=12"],
        flags={"planner": "grad"},
    )  # fmt: skip
    assert (s.optimiser.horizon_s, s.optimiser.samples, s.planner) == (0.75, 12, "grad")
    assert s.cost.w_keepout == 0.0  # the preset's, kept where nothing overrides it


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[cost]\nw_foo = 1\n", "unknown setting 'cost.w_foo' in"),
        ("horizon = 3\n", "unknown setting 'horizon' in"),
        ("[optimiser]\nknots = 2.5\n", "setting optimiser.knots must be int, got 2.5"),
        (
            "[optimiser]\nhorizon = 8\n",
            "setting 'optimiser.horizon' in .*bad.toml is now optimiser.horizon_s, in seconds",
        ),
        ("[cost]\nshaping_fade = 3\n", "setting cost.shaping_fade must be str, got 3"),
        ('[cost]\npre_push = "face"\n', "cost.pre_push is one of surface, circle, got 'face'"),
        ('[cost]\nshaping_at = "first"\n', "cost.shaping_at is one of last, every, got 'first'"),
        ('[rollout]\ncontact_margin_m = "1cm"\n', "must be off or float, got '1cm'"),
        ("optimiser = 3\n", "setting optimiser in"),
        ("[optimiser\n", "is not valid TOML"),
    ],
)
def test_a_bad_settings_file_is_refused_naming_the_setting(text, message, tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        resolve_settings(config=path)


def test_an_unknown_setting_on_the_command_line_is_exit_code_2(tmp_path, capsys):
    assert plan_push_main(["--goal", "0.1", "0", "0", "--set", "cost.w_nope=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown setting 'cost.w_nope'" in err[0]
    assert main(["trials", "--scenario", "tiny", "--n", "1", "--set", "nope",
                 "--out", str(tmp_path / "t")]) == 2  # fmt: skip
    assert "--set takes NAME=VALUE" in capsys.readouterr().err
    assert main(["config", "--config", str(tmp_path / "missing.toml")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["config", "--config", str(tmp_path)]) == 2
    assert "is a folder: give a TOML file" in capsys.readouterr().err
    (tmp_path / "binary.toml").write_bytes(b"\xff\xfe[cost]")
    assert main(["config", "--config", str(tmp_path / "binary.toml")]) == 2
    assert "is not UTF-8 text" in capsys.readouterr().err


def test_se3push_config_prints_settings_that_load_back(tmp_path, capsys):
    assert main(["config", "--preset", "horizon3", "--set", "optimiser.samples=20"]) == 0
    path = tmp_path / "printed.toml"
    path.write_text(capsys.readouterr().out)
    expected = dataclasses.replace(
        PRESETS["horizon3"],
        optimiser=dataclasses.replace(PRESETS["horizon3"].optimiser, samples=20),  # fmt: skip
    )
    assert resolve_settings(config=path) == expected


def test_each_preset_is_the_one_before_with_one_thing_taken_away():
    """The presets differ from their successor in what the planner before lacked, and
    nothing else (so a preset is the planner its records ran, not a new one)."""

    def flat(s):
        return {f"{k}.{j}": w for k, v in settings_dict(s).items() if isinstance(v, dict)
                for j, w in v.items()}  # fmt: skip

    order = [p for name, p in PRESETS.items() if name != "long"]  # the earlier planners
    changed = [
        sorted(k for k, v in flat(b).items() if flat(a)[k] != v)
        for a, b in zip(order, order[1:], strict=False)
    ]
    assert changed == [
        ["cost.pre_push"],
        ["cost.near_goal_m"],
        ["cost.w_keepout"],
        ["optimiser.horizon_s"],
        ["cost.shaping_fade"],
        ["rollout.contact_margin_m", "rollout.feedback"],
    ]
    # the long planner is today's looking further ahead, with the shaping charged at every step
    assert sorted(
        k for k, v in flat(PRESETS["long"]).items() if flat(PRESETS["default"])[k] != v
    ) == ["cost.shaping_at", "optimiser.horizon_s", "optimiser.knots", "optimiser.spline"]
