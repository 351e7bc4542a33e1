import numpy as np
import pytest

from evaluation.diagnostics import pauses, pooled
from planner.diagnostics import exploitation, step_figures


def _step(pred_mm, act_mm, pred_prog_mm=0.0, act_prog_mm=0.0):
    return {
        "predicted_disp_m": pred_mm * 1e-3,
        "actual_disp_m": act_mm * 1e-3,
        "predicted_progress_m": pred_prog_mm * 1e-3,
        "actual_progress_m": act_prog_mm * 1e-3,
    }


def test_phantom_and_missed_motion_on_a_hand_made_sequence():
    steps = [
        _step(5, 0.2),  # phantom: predicted a push, nothing moved
        _step(0.5, 0.1),  # still, predicted still
        _step(2, 0.5),  # still, predicted 2 mm: not phantom (threshold 3 mm)
        _step(0.2, 8),  # missed: moved 8 mm, predicted nothing
        _step(7, 6),  # moved, predicted
        _step(2, 2),  # neither still nor pushed
    ]
    d = exploitation(steps)
    assert (d["still_steps"], d["phantom_steps"]) == (3, 1)
    assert (d["moved_steps"], d["missed_steps"]) == (2, 1)
    assert d["phantom_rate"] == pytest.approx(1 / 3) and d["missed_rate"] == pytest.approx(0.5)


def test_progress_ratio_and_pooling():
    a = exploitation([_step(5, 5, 10, 4), _step(5, 5, 10, 6)])
    assert a["progress_ratio"] == pytest.approx(2.0)  # the model promised twice the progress
    b = exploitation([_step(5, 5, 4, 10)])
    assert b["progress_ratio"] == pytest.approx(0.4)
    both = pooled([a, b])
    assert both["progress_ratio"] == pytest.approx(24 / 20)
    assert both["moved_steps"] == 3 and both["phantom_rate"] is None  # no still step at all
    assert exploitation([_step(0, 0, 1, 0)])["progress_ratio"] is None  # no actual progress


def test_step_figures_measure_displacement_and_progress():
    goal = np.array([1.0, 0.0, 0.0])
    f = step_figures(np.zeros(3), np.array([0.1, 0.0, 0.3]), np.array([0.0, 0.05, 0.0]), goal)
    assert f["predicted_disp_m"] == pytest.approx(0.1)
    assert f["actual_disp_m"] == pytest.approx(0.05)
    assert f["predicted_progress_m"] == pytest.approx(0.1)
    assert f["actual_progress_m"] == pytest.approx(1.0 - np.hypot(1.0, 0.05))


def test_pauses_are_the_still_runs_between_two_pushes():
    # moved (>= 1 mm) at steps 2, 6 and 8; 0.5 mm counts as still
    disp_mm = [0, 0, 5, 0, 0.2, 0, 2, 0.5, 3, 0, 0]
    assert pauses([d * 1e-3 for d in disp_mm]) == [3, 1]
    assert pauses([0.0, 0.0]) == [] and pauses([0.01, 0.01]) == []
