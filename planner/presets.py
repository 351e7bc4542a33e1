"""Named planners: today's default, ``long`` (1.2 s ahead), and the earlier
ones that committed records were made with.

A record folder made with an earlier planner is reproduced with ``--preset NAME`` (its
``config.json`` holds the settings in full; ``se3push config --preset NAME`` prints them).
Each earlier planner is today's with what it lacked taken away, newest first.
"""

from __future__ import annotations

from dataclasses import replace

from planner.settings import PlanSettings, RolloutConfig
from scenarios import InputError


def _changed(s: PlanSettings, *, optimiser: dict | None = None, cost: dict | None = None,
             rollout: dict | None = None) -> PlanSettings:  # fmt: skip
    """``s`` with the given fields of its optimiser, cost and rollout settings changed."""
    return replace(
        s,
        optimiser=replace(s.optimiser, **(optimiser or {})),
        cost=replace(s.cost, **(cost or {})),
        rollout=replace(s.rollout, **(rollout or {})),
    )


DEFAULT = PlanSettings()
CIRCLE = _changed(DEFAULT, cost={"pre_push": "circle"})
KEEPOUT = _changed(CIRCLE, cost={"near_goal_m": 0.0})
HORIZON3 = _changed(KEEPOUT, cost={"w_keepout": 0.0})
FADE_BEHIND = _changed(HORIZON3, optimiser={"horizon_s": 0.6})
RENDERED_GATE = _changed(FADE_BEHIND, cost={"shaping_fade": "everywhere"})
GRID = replace(RENDERED_GATE, rollout=RolloutConfig(feedback="grid", contact_margin_m=None))
LONG = _changed(
    DEFAULT,
    optimiser={"horizon_s": 1.2, "knots": 4, "spline": "cubic"},
    cost={"shaping_at": "every"},
)

PRESETS: dict[str, PlanSettings] = {
    "default": DEFAULT,
    "circle": CIRCLE,
    "keepout": KEEPOUT,
    "horizon3": HORIZON3,
    "fade_behind": FADE_BEHIND,
    "rendered_gate": RENDERED_GATE,
    "grid": GRID,
    "long": LONG,
}
"""today's planner (``default``), then each planner before it, named as the record folders of
docs/results/trials/final name them: ``circle``, the pre-push point 2 cm beyond the circle that
holds the object's footprint (the default before the surface's, docs/planner.md; the
``default_*`` and ``oracle_*`` folders of docs/results/trials/headline);
``keepout``, the keep-out term not faded near the goal;
``horizon3``, no keep-out term; ``fade_behind``, 4 steps ahead; ``rendered_gate``, the shaping
term faded by predicted motion wherever the pusher is; ``grid``, predicted clouds fed back on
the observed grid and every predicted motion counted (no contact gate); and ``long``, today's
planner looking 1.2 s ahead through 4 cubic knots, with the shaping term charged at every step
of the plan (at its last only, a long plan puts off going round the object: docs/planner.md). The
``long`` of the headline's ``*_long_*`` folders was ``circle`` looking 1.2 s ahead through the
same knots without the keep-out term and the fade near the goal (their ``run.sh`` spells it
out)"""


def preset_settings(name: str) -> PlanSettings:
    """The settings of preset ``name``, or an InputError listing the presets."""
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
    return PRESETS[name]
