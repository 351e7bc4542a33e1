"""The one settings object of planning: optimiser, cost and rollout, nested and frozen.

``plan-push``, ``trials``, ``study``, ``improve``, ``bench`` and the Gymnasium environment all
take a :class:`PlanSettings`. Its common fields have flags; all of them can be set in a TOML
file (``--config FILE.toml``) or one at a time (``--set cost.w_keepout=0``);
``se3push config`` prints the defaults as TOML. Earlier planners are named presets
(``planner.presets``).

TOML has no null: a field whose value may be None (``rollout.contact_margin_m``,
``optimiser.warm_std``) is written ``"off"`` for None.
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any

from planner.base import PlannerConfig
from planner.cost import CostConfig
from planner.dynamics import CONTACT_MARGIN_M, PLAN_FEEDBACK, check_contact_margin
from scenarios import InputError
from se3net.rollout import FEEDBACK

OFF = "off"
"""how a None is written in TOML and on the command line"""


@dataclass(frozen=True)
class RolloutConfig:
    """How a learned model is rolled over the horizon (the simulator backends ignore it)."""

    feedback: str = PLAN_FEEDBACK
    """how each predicted cloud is fed back (``se3net.rollout.FEEDBACK``): ``rendered`` again by
    the camera, or on the observed ``grid``"""
    contact_margin_m: float | None = CONTACT_MARGIN_M
    """an object's predicted motion counts only where something passes within this margin of
    touching it (``planner.dynamics.contact_gate``); None: every predicted motion counts"""

    def __post_init__(self) -> None:
        if self.feedback not in FEEDBACK:
            raise InputError(
                f"rollout.feedback must be one of {', '.join(FEEDBACK)}, got {self.feedback!r}"
            )
        check_contact_margin(self.contact_margin_m)


@dataclass(frozen=True)
class PlanSettings:
    """Everything that decides a plan but the model and the goal."""

    planner: str = "cem"
    """the optimiser: cem, mppi, grad or sqp"""
    optimiser: PlannerConfig = PlannerConfig()
    """the optimisers' settings (each reads the ones it uses; horizon, samples…)"""
    cost: CostConfig = CostConfig()
    """the cost's terms and weights"""
    rollout: RolloutConfig = RolloutConfig()
    """how a learned model is rolled"""

    def __post_init__(self) -> None:
        from planner import PLANNERS

        if self.planner not in PLANNERS:
            raise InputError(f"unknown planner {self.planner!r}; known: {', '.join(PLANNERS)}")


RENAMED = {"optimiser.horizon": "optimiser.horizon_s, in seconds (0.15 s a control step)"}
"""settings that changed name, and what to write now"""


def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _convert(value: Any, kind: Any, where: str) -> Any:
    """``value`` (from TOML or the command line) as a field of type ``kind``, or an InputError."""
    args = typing.get_args(kind)
    optional = (typing.get_origin(kind) in (typing.Union, types.UnionType)) and type(None) in args
    if optional:
        if value is None or (isinstance(value, str) and value.lower() in (OFF, "none")):
            return None
        kind = next(a for a in args if a is not type(None))
    try:
        if kind is bool:
            if isinstance(value, str) and value.lower() in ("true", "false"):
                return value.lower() == "true"
            if isinstance(value, bool):
                return value
            raise ValueError
        if kind is int:
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise ValueError
            return int(value)
        if kind is float:
            if isinstance(value, bool):
                raise ValueError
            return float(value)
        if kind is str:
            if not isinstance(value, str):
                raise ValueError
            return value
    except (TypeError, ValueError):
        pass
    else:
        raise AssertionError(f"unhandled setting type {kind}")
    name = getattr(kind, "__name__", str(kind))
    raise InputError(
        f"setting {where} must be {'off or ' if optional else ''}{name}, got {value!r}"
    )


def _build(cls: type, values: dict[str, Any], prefix: str, source: str) -> Any:
    """An instance of dataclass ``cls`` from nested ``values`` (unknown keys refused)."""
    types_ = _field_types(cls)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        where = f"{prefix}{unknown[0]}"
        if where in RENAMED:
            raise InputError(f"setting {where!r}{source} is now {RENAMED[where]}")
        raise InputError(
            f"unknown setting {where!r}{source}; known in {prefix.rstrip('.') or 'the top level'}:"
            f" {', '.join(sorted(known))} (`se3push config` prints them all)"
        )
    kwargs = {}
    for name, value in values.items():
        kind = types_[name]
        if is_dataclass(kind):
            if not isinstance(value, dict):
                raise InputError(f"setting {prefix}{name}{source} is a table of settings")
            kwargs[name] = _build(kind, value, f"{prefix}{name}.", source)
        else:
            kwargs[name] = _convert(value, kind, f"{prefix}{name}")
    return cls(**kwargs)


def settings_from_dict(values: dict[str, Any], *, source: str = "") -> PlanSettings:
    """Settings from a nested dict (a TOML file's tables); fields not given keep their
    defaults. ``source`` (e.g. ``" in run.toml"``) is named in errors."""
    return _build(PlanSettings, values, "", source)


def settings_dict(settings: PlanSettings) -> dict[str, Any]:
    """The nested dict of ``settings`` (what records store)."""
    return dataclasses.asdict(settings)


def merged(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``changes`` laid over it, table by table."""
    out = dict(base)
    for k, v in changes.items():
        out[k] = merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def parse_assignment(text: str) -> dict[str, Any]:
    """``section.name=value`` (``--set``) as a nested dict; the value is converted later."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise InputError(f"--set takes NAME=VALUE (e.g. cost.w_keepout=0), got {text!r}")
    out: dict[str, Any] = {}
    node = out
    parts = key.strip().split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value.strip()
    return out


def read_toml(path: str | Path) -> dict[str, Any]:
    """A settings file's tables, or an InputError naming the file."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"--config {path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"--config {path} is a folder: give a TOML file") from None
    except UnicodeDecodeError:
        raise InputError(f"--config {path} is not UTF-8 text: give a TOML file") from None
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"--config {path} is not valid TOML: {err}") from None


def resolve_settings(
    *,
    preset: str | None = None,
    config: str | Path | None = None,
    assignments: list[str] | tuple[str, ...] = (),
    flags: dict[str, Any] | None = None,
) -> PlanSettings:
    """The settings of a command: a preset (default: today's planner), then a TOML file, then
    ``--set`` assignments, then the command's own flags (nested dict, None: not given)."""
    from planner.presets import preset_settings

    values = settings_dict(preset_settings(preset or "default"))
    if config is not None:
        values = merged(values, read_toml(config))
        settings_from_dict(values, source=f" in {config}")  # name the file in its errors
    for text in assignments:
        values = merged(values, parse_assignment(text))
    return settings_from_dict(merged(values, _given(flags or {})))


def _given(flags: dict[str, Any]) -> dict[str, Any]:
    """The flags a user gave: those that are not None, tables without their None fields."""
    out = {}
    for k, v in flags.items():
        if isinstance(v, dict):
            if given := _given(v):
                out[k] = given
        elif v is not None:
            out[k] = v
    return out


def _toml_value(value: Any) -> str:
    if value is None:
        return f'"{OFF}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, float):
        return repr(value)
    return str(value)


def settings_toml(settings: PlanSettings) -> str:
    """``settings`` as a TOML file: the top-level fields, then a table per section."""
    lines = ['# se3push planning settings (se3push config); None is written "off"', ""]
    top = [f for f in fields(PlanSettings) if not is_dataclass(_field_types(PlanSettings)[f.name])]
    for f in top:
        lines.append(f"{f.name} = {_toml_value(getattr(settings, f.name))}")
    for f in fields(PlanSettings):
        section = getattr(settings, f.name)
        if not is_dataclass(section):
            continue
        lines += ["", f"[{f.name}]"]
        for g in fields(section):
            lines.append(f"{g.name} = {_toml_value(getattr(section, g.name))}")
    return "\n".join(lines) + "\n"
