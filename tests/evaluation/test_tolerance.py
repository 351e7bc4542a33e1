"""Success at any tolerance: the loop runs on to the one asked for; summaries and compare
report every tolerance the trials measured, and refuse one they stopped short of."""

import json
from dataclasses import replace

import pytest

from evaluation.compare import compare_trials, format_comparison
from evaluation.trials import summarize
from planner.diagnostics import exploitation
from planner.loop import PRECISE, TIGHT, PushConfig, check_tolerance, run_push
from scenarios import InputError
from se3push.cli import main
from tests.planner.test_loop import _nearby_goal


def _record(i, errors_cm_deg, ran_to):
    pos_cm, yaw = errors_cm_deg
    within = {name: pos_cm <= m * 100 and yaw <= d for name, (m, d) in
              {"precise": (0.01, 5), "tight": (0.02, 10), "loose": (0.05, 20)}.items()}  # fmt: skip
    return {"trial": i, "reset_seed": i, "start": [0.0, 0.0, 0.0], "goal": [0.1, 0.0, 0.0],
            **{f"success_{k}": v for k, v in within.items()}, "tolerance": list(ran_to),
            "final_pos_err_m": pos_cm / 100, "final_yaw_err_deg": yaw, "steps": 10,
            "replan_ms_median": 1.0, "diagnostics": exploitation([])}  # fmt: skip


ERRORS = [(0.5, 2.0), (1.5, 4.0), (0.8, 7.0), (3.0, 15.0)]
"""final errors (cm, deg): within precise, tight only, tight only (yaw), loose only"""


def test_summaries_give_each_tolerance_the_trials_ran_to_and_none_they_stopped_short_of():
    precise = summarize([_record(i, e, PRECISE) for i, e in enumerate(ERRORS)])
    assert (precise["success_precise"], precise["success_tight"],
            precise["success_loose"]) == (0.25, 0.75, 1.0)  # fmt: skip
    assert precise["success_precise_ci95"][0] < 0.25 < precise["success_precise_ci95"][1]
    tight = summarize([_record(i, e, TIGHT) for i, e in enumerate(ERRORS)])
    assert tight["success_precise"] is None and tight["success_tight"] == 0.75
    mixed = [_record(0, ERRORS[0], PRECISE), _record(1, ERRORS[1], TIGHT)]
    assert summarize(mixed)["success_precise"] is None
    old = [{k: v for k, v in _record(0, ERRORS[0], TIGHT).items() if k != "tolerance"}]
    assert summarize(old)["success_precise"] is None  # records from before ran to tight


def _folder(path, ran_to, errors):
    path.mkdir()
    config = {"schema": 2, "scenario": "tiny", "seed": 0, "n": len(errors), "trial_set": 2,
              "tolerance": list(ran_to)}  # fmt: skip
    (path / "config.json").write_text(json.dumps(config))
    lines = [json.dumps(_record(i, e, ran_to)) for i, e in enumerate(errors)]
    (path / "trials.jsonl").write_text("\n".join(lines) + "\n")
    return path


def test_compare_pairs_every_tolerance_both_folders_measured(tmp_path, capsys):
    a = _folder(tmp_path / "a", PRECISE, ERRORS)
    b = _folder(tmp_path / "b", PRECISE, [(1.5, 2.0), (0.5, 2.0), (0.8, 7.0), (6.0, 1.0)])
    c = compare_trials(a, b, tolerance="precise")
    assert (c["successes_a"], c["successes_b"], c["wins"], c["losses"]) == (1, 1, 1, 1)
    assert list(c["by_tolerance"]) == ["precise", "tight", "loose"]
    assert c["by_tolerance"]["loose"]["wins"] == 1  # B's last push ends 6 cm off
    assert c["by_tolerance"]["tight"]["wins"] == c["by_tolerance"]["tight"]["losses"] == 0
    text = format_comparison(c)
    assert "at tight (2 cm & 10°)" in text and "at loose (5 cm & 20°)" in text
    old = _folder(tmp_path / "old", TIGHT, ERRORS)
    with pytest.raises(InputError, match="ran its trials to a looser tolerance than precise"):
        compare_trials(a, old, tolerance="precise")
    assert list(compare_trials(a, old)["by_tolerance"]) == ["tight", "loose"]
    assert main(["compare", str(a), str(old), "--tolerance", "precise"]) == 2


def test_the_loop_runs_on_to_the_tolerance_asked_for():
    goal = _nearby_goal(0.03)  # the tight push stops between 1 and 2 cm of it
    tight = run_push(PushConfig(goal=goal, scenario="tiny", model="oracle", max_steps=30))
    precise = run_push(PushConfig(goal=goal, scenario="tiny", model="oracle", max_steps=30,
                                  tolerance="precise"))  # fmt: skip
    assert tight.reason == precise.reason == "reached"
    assert tight.success_tight and not tight.success_precise  # it stopped at 2 cm, 10 deg
    assert precise.success_precise and precise.steps > tight.steps
    untimed = [[replace(r, replan_ms=0.0) for r in res.records] for res in (precise, tight)]
    assert untimed[0][: tight.steps] == untimed[1]  # the same push until then
    assert precise.tolerance == PRECISE and tight.tolerance == TIGHT


@pytest.mark.parametrize("bad", ["exact", (0.0, 5.0), (0.01, float("nan"))])
def test_a_bad_tolerance_is_refused(bad):
    with pytest.raises(InputError, match="--tolerance"):
        check_tolerance(bad)
