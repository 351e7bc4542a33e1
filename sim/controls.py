"""What an action commands, and the control vector ``u`` a network gets, per scenario.

A scenario's ``action.controls`` says what one action is:

- ``"pusher"``: the pusher's planar velocity ``(vx, vy)`` (m/s), which the differential-IK
  controller turns into joint motion. The network's controls are the command and the pusher's
  position at the step's start, integrated from the commands when the planner rolls a model
  forward (the paper's box data fed the ball's pose beside the force in the same way).
- ``"joints"``: the commanded velocities (rad/s) of the arm's 4 joints, 1-4 of them non-zero,
  as in the paper's Baxter data, whose controls were the commanded joint velocities alone
  (n = 14 there, for two 7-joint arms); so are ours (n = 4): the arm's configuration is in
  the cloud the network sees.

A :class:`ControlLayout` names the entries of ``u``: first the commands (the action), then the
state integrated from them, if any. Datasets and checkpoints store the names; one layout per
kind of controls, so what a dataset holds picks its layout.
"""

from __future__ import annotations

from dataclasses import dataclass

from scenarios import Scenario
from sim.mjcf import ARM_JOINTS


@dataclass(frozen=True)
class ControlLayout:
    """The entries of a control vector ``u``: ``commands`` then ``integrated``."""

    controls: str
    """the scenarios' ``action.controls`` this layout serves"""
    commands: tuple[str, ...]
    """the action's entries, held for one control step"""
    integrated: tuple[str, ...] = ()
    """state at the step's start, integrated from the commands over a rollout (as many
    entries as ``commands``, or none)"""
    state_key: str | None = None
    """the dataset array that records the integrated state per frame"""

    @property
    def names(self) -> tuple[str, ...]:
        """Every entry of ``u``, in order (what manifests and checkpoints store)."""
        return self.commands + self.integrated


PUSHER_LAYOUT = ControlLayout(
    "pusher", ("vx_m_s", "vy_m_s"), ("pusher_x_m", "pusher_y_m"), state_key="pusher_xy"
)
JOINT_LAYOUT = ControlLayout("joints", tuple(f"{j}_vel_rad_s" for j in ARM_JOINTS))
LAYOUTS = (PUSHER_LAYOUT, JOINT_LAYOUT)


def control_layout(scenario: Scenario) -> ControlLayout:
    """The layout of a scenario's controls."""
    return next(layout for layout in LAYOUTS if layout.controls == scenario.action.controls)


def layout_named(names: list[str] | tuple[str, ...]) -> ControlLayout | None:
    """The layout whose ``names`` these are (as a manifest or checkpoint stores them), or None
    for a layout this code does not know."""
    return next((layout for layout in LAYOUTS if list(layout.names) == list(names)), None)
