from pathlib import Path

import pytest

from scenarios import ScenarioError, list_scenarios, load_scenario

PACKAGED = Path(__file__).resolve().parents[2] / "scenarios"


def test_packaged_scenarios_load_with_descriptions():
    names = list_scenarios()
    assert {"single_box", "multi_object", "tiny"} <= set(names)
    assert all(len(d) > 10 for d in names.values())
    s = load_scenario("multi_object")
    assert s.objects.count == (1, 3)
    assert set(s.objects.shapes) == {"box", "cylinder"}
    assert load_scenario("tiny").camera.width == 32


def test_unknown_scenario_lists_known_ones():
    with pytest.raises(ScenarioError, match="unknown scenario 'nope'.*single_box.*tiny"):
        load_scenario("nope")


def _variant(tmp_path: Path, old: str, new: str) -> Path:
    text = (PACKAGED / "tiny.toml").read_text()
    assert old in text
    path = tmp_path / "variant.toml"
    path.write_text(text.replace(old, new, 1))
    return path


def test_malformed_toml_names_the_file(tmp_path):
    path = _variant(tmp_path, "[table]", "[table")
    with pytest.raises(ScenarioError, match=r"variant\.toml: malformed TOML"):
        load_scenario(path)


@pytest.mark.parametrize(
    ("old", "new", "pattern"),
    [
        (
            "thickness_m = 0.03",
            'thickness_m = "thick"',
            r"'table\.thickness_m': expected a number, found 'thick'",
        ),
        ("width = 32", "width = 32.5", r"'camera\.width': expected an integer, found 32\.5"),
        ("width = 32", "width = 2", r"'camera\.width': expected values >= 8, found 2"),
        ("fovy_deg = 45.0", "fovy_deg = -5.0", r"'camera\.fovy_deg': expected values > 1"),
        (
            "mass_kg = [0.2, 0.2]",
            "mass_kg = [0.3, 0.2]",
            r"'objects\.mass_kg': expected \[lo, hi\] pairs",
        ),
        ('shapes = ["box"]', 'shapes = ["sphere"]', r"'objects\.shapes': expected entries from"),
        ("count = [1, 1]", "count = [1, 4]", r"'objects\.count': expected values <= 3"),
        ("size_m = [0.3, 0.3]", "size_m = [0.3]", r"'table\.size_m': expected a list of 2"),
        (
            "depth_sd_scaled = false",
            "depth_sd_scaled = 0",
            r"'noise\.depth_sd_scaled': expected true/false",
        ),
        (
            "friction = 0.5\n",
            "friction = 0.5\nfrction = 1.0\n",
            r"'table\.frction': expected one of",
        ),
        ("max_speed_m_s = 0.15\n", "", r"'action\.max_speed_m_s' is missing"),
        (
            "controller_rate_hz = 100.0",
            "controller_rate_hz = 30.0",
            r"'arm\.controller_rate_hz': expected a rate whose period is a whole number",
        ),
        (
            "physics_dt_s = 0.002",
            "physics_dt_s = 0.004",
            r"'action\.dt_control_s': expected a whole number of action\.physics_dt_s",
        ),
    ],
)
def test_bad_fields_name_file_field_expected_and_found(tmp_path, old, new, pattern):
    path = _variant(tmp_path, old, new)
    with pytest.raises(ScenarioError, match=r"variant\.toml: .*" + pattern):
        load_scenario(path)


def test_scenarios_are_frozen():
    s = load_scenario("tiny")
    with pytest.raises(AttributeError):
        s.table.friction = 1.0  # type: ignore[misc]


def test_a_folder_named_like_a_scenario_does_not_hide_it(tmp_path, monkeypatch):
    """``--scenario tiny --out tiny``: the data folder the run makes is not the scenario."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny").mkdir()
    assert load_scenario("tiny").name == "tiny"


def test_a_scenario_file_that_is_not_text_is_refused_in_one_line(tmp_path):
    path = tmp_path / "bin.toml"
    path.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(ScenarioError, match="bin.toml is not a UTF-8 text file"):
        load_scenario(path)
