"""Load and validate scenario TOML files into frozen dataclasses.

A scenario is named by a file stem in this package (``single_box``) or by a path to a TOML
file. Every problem is reported as a :class:`ScenarioError` naming the file, the field, what
was expected and what was found.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from importlib import resources
from pathlib import Path
from typing import Any

from scenarios.config import Scenario
from scenarios.errors import InputError


class ScenarioError(InputError):
    """A scenario could not be found, parsed or validated."""


def list_scenarios() -> dict[str, str]:
    """Names of the packaged scenarios, each with its one-line description."""
    out = {}
    for entry in sorted(resources.files("scenarios").iterdir(), key=lambda p: p.name):
        if entry.name.endswith(".toml"):
            out[entry.name[:-5]] = load_scenario(entry.name[:-5]).description
    return out


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a packaged scenario by name, or any scenario TOML by path.

    Raises:
        ScenarioError: unknown name, unreadable file, malformed TOML or an invalid field.
    """
    text, where, stem = _read(name_or_path)
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ScenarioError(f"{where}: malformed TOML: {err}") from None
    table.setdefault("name", stem)
    return _checked(_build(Scenario, table, where, ""), where)


def scenario_from_dict(table: dict[str, Any], *, where: str = "stored scenario") -> Scenario:
    """Rebuild (and validate) a scenario from ``scenarios.config.scenario_dict`` output (or
    ``dataclasses.asdict``), e.g. the copy a dataset manifest or a checkpoint keeps; fields
    with a default that it leaves out get their default."""
    return _checked(_build(Scenario, table, where, ""), where)


def _checked(s: Scenario, where: str) -> Scenario:
    """Refuse combinations of fields that cannot work together."""
    steps = s.action.dt_control_s / s.action.physics_dt_s
    if abs(steps - round(steps)) > 1e-6 * steps:  # the world holds each action whole steps
        raise _fail(where, "action.dt_control_s", "a whole number of action.physics_dt_s "
                    f"({s.action.physics_dt_s})", s.action.dt_control_s)  # fmt: skip
    ticks = 1.0 / (s.arm.controller_rate_hz * s.action.physics_dt_s)
    if abs(ticks - round(ticks)) > 1e-6 * ticks or round(steps) % max(1, round(ticks)):
        raise _fail(where, "arm.controller_rate_hz", "a rate whose period is a whole number "
                    "of physics steps that divides the action's (else the last tick of each "
                    "action is held short and the pusher runs fast)",
                    s.arm.controller_rate_hz)  # fmt: skip
    count = list(s.objects.count)
    if s.action.controls == "joints" and count != [0, 0]:
        raise _fail(where, "objects.count", "[0, 0] with action.controls 'joints' (the arm "
                    "moves alone, as in the paper's Baxter data)", count)  # fmt: skip
    if s.action.controls == "pusher" and count[0] < 1:
        raise _fail(where, "objects.count", "at least 1 object with action.controls 'pusher' "
                    "(pushes need something to push)", count)  # fmt: skip
    if s.arm.links_visible and count != [0, 0]:
        raise _fail(where, "objects.count", "[0, 0] with arm.links_visible (the links take "
                    "the objects' part labels)", count)  # fmt: skip
    return s


def _read(name_or_path: str | Path) -> tuple[str, str, str]:
    """The text of a scenario, where it came from and its default name. A name without
    ``.toml`` is a packaged scenario's whenever there is one, whatever the working directory
    holds (a data folder named ``single_box`` must not hide the scenario)."""
    path = Path(name_or_path)
    resource = resources.files("scenarios") / f"{name_or_path}.toml"
    packaged = path.suffix != ".toml" and "/" not in str(name_or_path) and resource.is_file()
    if packaged:
        text, where, stem = resource.read_bytes(), f"scenarios/{name_or_path}.toml", path.name
    elif path.suffix == ".toml" or path.is_file():
        if not path.is_file():
            raise ScenarioError(f"scenario file {path} does not exist")
        text, where, stem = path.read_bytes(), str(path), path.stem
    else:
        known = ", ".join(_packaged_names())
        raise ScenarioError(
            f"unknown scenario {str(name_or_path)!r}; known scenarios: {known} "
            "(or give a path to a .toml file)"
        )
    try:
        return text.decode("utf-8"), where, stem
    except UnicodeDecodeError:
        raise ScenarioError(f"{where} is not a UTF-8 text file (a scenario is TOML)") from None


def _packaged_names() -> list[str]:
    return sorted(
        e.name[:-5] for e in resources.files("scenarios").iterdir() if e.name.endswith(".toml")
    )


def _fail(where: str, field: str, expected: str, found: Any) -> ScenarioError:
    return ScenarioError(f"{where}: field '{field}': expected {expected}, found {found!r}")


def _build(cls: type, table: Any, where: str, prefix: str) -> Any:
    if not isinstance(table, dict):
        raise _fail(where, prefix.rstrip("."), "a table", table)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise _fail(where, prefix + unknown[0], f"one of {sorted(fields)}", "an unknown field")
    values = {}
    for name, f in fields.items():
        dotted = prefix + name
        if name not in table:
            if f.default is not dataclasses.MISSING:
                values[name] = f.default
                continue
            raise ScenarioError(f"{where}: field '{dotted}' is missing ({f.metadata['doc']})")
        hint = hints[name]
        if dataclasses.is_dataclass(hint):
            values[name] = _build(hint, table[name], where, dotted + ".")
        else:
            values[name] = _coerce(table[name], hint, where, dotted)
            _check_limits(values[name], f.metadata, where, dotted)
    return cls(**values)


def _describe(hint: Any) -> str:
    origin = typing.get_origin(hint)
    if origin is tuple:
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_describe(args[0])}"
        return f"a list of {len(args)} " + " ".join(_describe(a) for a in args[:1])
    return {float: "number", int: "integer", bool: "true/false", str: "string"}.get(hint, str(hint))


def _coerce(value: Any, hint: Any, where: str, field: str) -> Any:
    origin = typing.get_origin(hint)
    if origin is tuple:
        args = typing.get_args(hint)
        variadic = len(args) == 2 and args[1] is Ellipsis
        if not isinstance(value, list) or (not variadic and len(value) != len(args)):
            raise _fail(where, field, _describe(hint), value)
        items = args[:1] * len(value) if variadic else args
        return tuple(_coerce(v, a, where, field) for v, a in zip(value, items, strict=True))
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _fail(where, field, "a number", value)
        if not math.isfinite(value):
            raise _fail(where, field, "a finite number", value)
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(where, field, "an integer", value)
        return value
    if hint is bool or hint is str:
        if not isinstance(value, hint):
            raise _fail(where, field, _describe(hint), value)
        return value
    raise TypeError(f"unsupported field type {hint}")


def _numbers(value: Any) -> list[float]:
    if isinstance(value, tuple):
        return [x for v in value for x in _numbers(v)]
    if isinstance(value, int | float) and not isinstance(value, bool):
        return [value]
    return []


def _check_limits(value: Any, meta: Any, where: str, field: str) -> None:
    for x in _numbers(value):
        if "gt" in meta and not x > meta["gt"]:
            raise _fail(where, field, f"values > {meta['gt']}", value)
        if "ge" in meta and not x >= meta["ge"]:
            raise _fail(where, field, f"values >= {meta['ge']}", value)
        if "le" in meta and not x <= meta["le"]:
            raise _fail(where, field, f"values <= {meta['le']}", value)
    if "min_len" in meta and len(value) < meta["min_len"]:
        raise _fail(where, field, f"at least {meta['min_len']} entries", value)
    if "choices" in meta:
        values = (value,) if isinstance(value, str) else value
        bad = [v for v in values if v not in meta["choices"]]
        if bad:
            raise _fail(where, field, f"entries from {list(meta['choices'])}", bad[0])
    if meta.get("ordered"):
        pairs = value if value and isinstance(value[0], tuple) else (value,)
        for pair in pairs:
            if len(pair) != 2 or pair[0] > pair[1]:
                raise _fail(where, field, "[lo, hi] pairs with lo <= hi", list(pair))
