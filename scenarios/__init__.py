"""Scenario files (TOML) and their frozen, validated configuration dataclasses."""

from scenarios.config import (
    ActionConfig,
    ArmConfig,
    CameraConfig,
    GoalsConfig,
    NoiseConfig,
    ObjectsConfig,
    Scenario,
    TableConfig,
)
from scenarios.errors import InputError, check_seed
from scenarios.loader import ScenarioError, list_scenarios, load_scenario, scenario_from_dict

__all__ = [
    "ActionConfig",
    "ArmConfig",
    "CameraConfig",
    "GoalsConfig",
    "InputError",
    "NoiseConfig",
    "ObjectsConfig",
    "Scenario",
    "ScenarioError",
    "TableConfig",
    "check_seed",
    "list_scenarios",
    "load_scenario",
    "scenario_from_dict",
]
