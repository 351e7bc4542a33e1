"""The record schema: every committed record folder loads through the one migration, pairs
with ``se3push compare``, and the final/ folders of earlier planners are their presets."""

import json
from pathlib import Path

import pytest

from evaluation.compare import compare_trials, read_trials
from evaluation.records import SCHEMA, migrate_config, migrate_record
from evaluation.trials import TrialsConfig, run_trials
from planner.presets import PRESETS, preset_settings
from planner.settings import settings_dict, settings_from_dict
from tests.evaluation.test_trials import _as_schema_1

ROOT = Path(__file__).resolve().parents[2]
FOLDERS = sorted(p.parent for p in (ROOT / "docs" / "results").rglob("trials.jsonl"))


def test_the_tree_holds_record_folders():
    assert len(FOLDERS) > 100  # the glob finds them: the test below can fail


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: str(p.relative_to(ROOT / "docs")))
def test_every_committed_record_folder_loads_through_the_one_schema_and_pairs(folder):
    config, records = read_trials(folder)
    meta = migrate_config(config)
    assert meta["schema"] == SCHEMA
    plan = meta["plan"]
    if {"optimiser", "cost", "rollout"} <= set(plan) and len(plan["optimiser"]) == len(
        settings_dict(preset_settings("default"))["optimiser"]
    ):  # a folder that recorded every setting: they build today's settings object
        settings_from_dict(plan)
    assert all("motion_gain" not in migrate_record(r) for r in records.values())
    pair = compare_trials(folder, folder)
    assert pair["n"] == len(records) and pair["wins"] == pair["losses"] == 0


def _norm(plan):
    plan = json.loads(json.dumps(plan))
    plan["optimiser"]["seed"] = 0
    return plan


@pytest.mark.parametrize(
    ("folder", "preset"),
    [
        ("headline/default_surface_single_box", "default"),
        ("headline/oracle_heldout_objects", "circle"),
        ("headline/default_h12_multi_object", "long"),
        ("final/default_near_goal_single_box", "circle"),
        ("final/default_keepout_multi_object", "keepout"),
        ("final/default_horizon3_heldout_objects", "horizon3"),
        ("final/oracle_fade_behind_single_box", "fade_behind"),
        ("final/default_rendered_gate_multi_object", "rendered_gate"),
        ("final/default_single_box", "grid"),
    ],
)
def test_the_records_of_an_earlier_planner_ran_its_preset(folder, preset):
    config = json.loads((ROOT / "docs/results/trials" / folder / "config.json").read_text())
    assert _norm(migrate_config(config)["plan"]) == _norm(settings_dict(PRESETS[preset]))


@pytest.mark.parametrize("model", ["default", "oracle"])
def test_the_earlier_long_records_ran_the_flags_their_script_gives(model):
    """The headline's ``*_long_*`` folders were made by ``--preset long`` before the preset
    became today's 1.2 s plan; ``run.sh`` now spells that planner out (``OLD_LONG``), and its
    flags give the settings the records ran."""
    import shlex

    from planner.settings import resolve_settings

    script = (ROOT / "docs/results/trials/headline/run.sh").read_text()
    line = next(x for x in script.splitlines() if x.startswith("OLD_LONG="))
    words = shlex.split(shlex.split(line.partition("=")[2])[0])
    preset = words[words.index("--preset") + 1]
    sets = [words[i + 1] for i, w in enumerate(words) if w == "--set"]
    settings = resolve_settings(preset=preset, assignments=sets)
    for s in ("single_box", "multi_object", "heldout_objects"):
        folder = ROOT / f"docs/results/trials/headline/{model}_long_{s}"
        config = json.loads((folder / "config.json").read_text())
        assert _norm(migrate_config(config)["plan"]) == _norm(settings_dict(settings))
    assert settings != PRESETS["long"]


def test_a_schema_1_folder_continues_under_its_preset_with_the_same_records(tmp_path):
    """A folder written as the code before the settings object wrote it (the horizon3 planner,
    its settings flat and nested as then) is extended by ``--preset horizon3``; its first trial,
    run afresh under the preset, is the same record but the wall clock."""
    cfg = TrialsConfig("tiny", n=2, model="oracle", max_steps=8, plan=PRESETS["horizon3"])
    run_trials(cfg, tmp_path / "old", progress=False)
    _as_schema_1(tmp_path / "old")
    assert "schema" not in json.loads((tmp_path / "old" / "config.json").read_text())
    assert run_trials(TrialsConfig("tiny", n=3, model="oracle", max_steps=8,
                                   plan=preset_settings("horizon3")), tmp_path / "old",
                      progress=False)["trials"] == 3  # fmt: skip
    run_trials(TrialsConfig("tiny", n=1, model="oracle", max_steps=8,
                            plan=preset_settings("horizon3")), tmp_path / "new",
               progress=False)  # fmt: skip

    def first(name):
        rec = json.loads((tmp_path / name / "trials.jsonl").read_text().splitlines()[0])
        return {k: v for k, v in rec.items() if k != "replan_ms_median"}

    assert first("old") == first("new")


def test_a_schema_2_folder_gave_its_horizon_in_steps_and_reads_in_seconds():
    """Schema 2 recorded ``optimiser.horizon`` in control steps of 0.15 s: the long-horizon dev
    folder planned 8 of them, 1.2 s, and reads as today's settings object with that horizon."""
    folder = ROOT / "docs/results/trials/dev_long/default_long"
    config = json.loads((folder / "config.json").read_text())
    assert config["schema"] == 2 and config["plan"]["optimiser"]["horizon"] == 8
    plan = migrate_config(config)["plan"]
    assert "horizon" not in plan["optimiser"] and plan["optimiser"]["horizon_s"] == 1.2
    assert settings_from_dict(plan).optimiser.steps(0.15) == 8
