"""The record schema: what a run folder's ``config.json`` holds, and the one migration from
every earlier layout to today's.

Schema 3 (today's): the run's own fields (scenario, n, model, seed, max_steps…) and ``plan``,
the nested planning settings (``planner.settings.PlanSettings``: ``planner``, ``optimiser``,
``cost``, ``rollout``), plus ``retired``: settings of options since removed from the package,
where the run used one (such a folder can be read and compared, not extended).

Schema 2 was schema 3 with the horizon in control steps (``optimiser.horizon``), not seconds
(``optimiser.horizon_s``).

Schema 1 (no ``schema`` key) is every folder from before: trial folders nested the optimiser's
settings (``planning``) and the cost's (``cost``) beside flat rollout settings (``feedback``,
``contact_margin_m``, ``motion_gain``); study and improve runs flattened a few of them under
other names (``horizon``, ``keepout_weight``, ``edge_weight``…). A setting a record lacks was
added after it was made, so the record ran as the code ran before the setting existed:
:data:`BEFORE` says how.
"""

from __future__ import annotations

import copy
from dataclasses import asdict
from typing import Any

from planner.loop import TIGHT
from planner.settings import PlanSettings

SCHEMA = 3
"""the layout of today's records"""

STEP_S = 0.15
"""how long every push scenario holds an action (the paper's 0.15 s): records of schemas 1 and
2 gave the horizon in these steps"""

BEFORE = {
    "optimiser": {"horizon_s": round(4 * STEP_S, 9), "knots": 0, "spline": "linear"},
    "cost": {
        "w_disturb": 0.0,
        "shaping_fade": "everywhere",
        "w_keepout": 0.0,
        "near_goal_m": 0.0,
        "pre_push": "circle",
        "shaping_at": "last",
    },
    "rollout": {"feedback": "grid", "contact_margin_m": None},
}
"""how a record that lacks a setting ran: 4 steps ahead (study and improve runs from before
they recorded the horizon), a plan of one value per step (no knots); no disturbance term, the
shaping term faded wherever the pusher was, no keep-out term, neither faded near the goal, the
pre-push point on the circle about the object, the shaping term charged at the last step only;
predicted clouds fed back on the grid, every predicted motion counted"""

RETIRED_SETTINGS = {
    ("rollout", "push_out"): False,
    ("optimiser", "model_s"): None,
    ("rollout", "gate"): "circle",
    ("cost", "turn_push"): 0.0,
    ("cost", "discount"): 1.0,
    ("optimiser", "near_horizon_s"): None,
    ("optimiser", "near_horizon_m"): 0.05,
    ("optimiser", "stall_horizon_s"): None,
    ("optimiser", "stall_knots"): 4,
    ("optimiser", "stall_steps"): 5,
    ("optimiser", "push_steps"): None,
    ("rollout", "exact_pusher"): False,
    ("optimiser", "short_horizon_s"): None,
    ("optimiser", "trusted_error_m"): 0.003,
}
"""retired options that were planning settings of schema 3, by section and name, with the
value that means "not used": a learned model's object pushed out of the pusher's path; objects
held after the model's first steps; the contact gate measured to the object's points; the
pre-push point moved off the centre line to turn the object; the pose terms discounted per
step; a horizon that shortens near the goal, whose distance means nothing without it; a
horizon that grows when the push stalls, whose knots and steps mean nothing without it; a
predicted push counted for a few steps of contact only; the pusher's points moved by its
commands in a learned rollout; a horizon that shortens while the model's one-step predictions
miss, whose threshold means nothing without it (docs/experiments)"""

RETIRED = {"motion_gain": "off", "w_edge": 0.0, "rollout_steps": 1}
"""options removed from the package that a schema-1 record may hold, with the value that means
"not used": a gain fitted to the push's own steps; a term keeping the object off the table's
edge; improve's multi-step fine-tuning (the retired planning settings of later schemas are
:data:`RETIRED_SETTINGS`)"""

SINCE_FLAT = {("cost", "pre_push")}
"""settings added after the last flat (study, improve) run was made: such a run ran them as
:data:`BEFORE` says"""

FLAT = {
    "horizon": ("optimiser", "horizon"),  # in steps: _horizon_in_seconds
    "shaping_fade": ("cost", "shaping_fade"),
    "keepout_weight": ("cost", "w_keepout"),
    "near_goal_m": ("cost", "near_goal_m"),
    "edge_weight": ("cost", "w_edge"),
    "feedback": ("rollout", "feedback"),
    "contact_margin_m": ("rollout", "contact_margin_m"),
}
"""schema-1 fields outside the nested tables, and where they belong"""


def _motion_gain(recorded: Any) -> Any:
    """Records from before the per-contact gain stored True (one gain, ``online``) or False."""
    if isinstance(recorded, bool):
        return "online" if recorded else "off"
    return recorded


def _horizon_in_seconds(plan: dict[str, Any]) -> None:
    """A horizon recorded in control steps (``optimiser.horizon``), in seconds, in place."""
    optimiser = plan.get("optimiser", {})
    if "horizon" in optimiser:
        optimiser["horizon_s"] = round(optimiser.pop("horizon") * STEP_S, 9)


def migrate_config(meta: dict[str, Any]) -> dict[str, Any]:
    """A run folder's ``config.json`` of any schema, in today's (a new dict; today's records
    are returned as they are)."""
    if meta.get("schema") in (2, SCHEMA):  # settings added since it was written ran as before
        plan = copy.deepcopy(meta.get("plan", {}))
        _horizon_in_seconds(plan)
        for section, fields in BEFORE.items():
            for field, value in fields.items():
                plan.setdefault(section, {}).setdefault(field, value)
        retired = dict(meta.get("retired", {}))
        for (section, name), unused in RETIRED_SETTINGS.items():
            value = plan.get(section, {}).pop(name, unused)
            if value != unused:
                retired[name] = value
        return {**meta, "schema": SCHEMA, "plan": plan, "retired": retired}
    old = copy.deepcopy(meta)
    flat = "planning" not in old  # a study or improve run: the rest were the defaults
    plan: dict[str, Any] = {
        "planner": old.pop("planner", "cem"),
        "optimiser": old.pop("planning", {}),
        "cost": old.pop("cost", {}),
        "rollout": {},
    }
    for name, (section, field) in FLAT.items():
        if name in old:
            plan[section][field] = old.pop(name)
    _horizon_in_seconds(plan)
    for section, fields in BEFORE.items():
        for field, value in fields.items():
            # a flat run could only have lacked the settings it flattened; the rest were the
            # defaults of the time, today's
            flattened = (section, "horizon" if field == "horizon_s" else field) in FLAT.values()
            if not flat or flattened or (section, field) in SINCE_FLAT:
                plan[section].setdefault(field, value)
    if flat:
        defaults = asdict(PlanSettings())
        for section in ("optimiser", "cost", "rollout"):
            plan[section] = {**defaults[section], **plan[section]}
    retired = {}
    gain = _motion_gain(old.pop("motion_gain", RETIRED["motion_gain"]))
    if gain != RETIRED["motion_gain"]:
        retired["motion_gain"] = gain
    edge = plan["cost"].pop("w_edge", RETIRED["w_edge"])
    if edge != RETIRED["w_edge"]:
        retired["w_edge"] = edge
    steps = old.pop("rollout_steps", RETIRED["rollout_steps"])
    if steps != RETIRED["rollout_steps"]:
        retired["rollout_steps"] = steps
    if "n" in old and "scenario" in old and "models" not in old:  # a trial set
        old.setdefault("tolerance", list(TIGHT))  # trials ran to 2 cm, 10 deg before
    return {"schema": SCHEMA, **old, "plan": plan, "retired": retired}


def migrate_record(rec: dict[str, Any]) -> dict[str, Any]:
    """A trial record (a ``trials.jsonl`` line) of any schema, in today's: the fields of retired
    options dropped (their configuration says what the run used)."""
    return {k: v for k, v in rec.items() if k not in ("motion_gain", "glancing_gain")}
