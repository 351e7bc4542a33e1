"""Trial summaries as people read them: table cells and the printed summary of a trial set.

Evaluation returns data (``evaluation.trials.summarize``); this module formats it.
"""

from __future__ import annotations

from typing import Any

from planner.loop import TOLERANCES


def fmt(x: Any, spec: str = ".3f") -> str:
    """A figure for a table, or a dash where it is undefined (None)."""
    return "–" if x is None else format(x, spec)


def summary_cells(s: dict[str, Any]) -> dict[str, str]:
    """The success and diagnostics figures of a summary, formatted for the tables that show
    them (trials, study, improve rounds)."""
    d = s["diagnostics"]
    (lo, hi), (lo2, hi2) = s["success_tight_ci95"], s["success_loose_ci95"]
    return {
        "tight": f"{s['success_tight']:.0%} [{lo:.0%}–{hi:.0%}]",
        "loose": f"{s['success_loose']:.0%} [{lo2:.0%}–{hi2:.0%}]",
        "phantom": fmt(d["phantom_rate"], ".0%"),
        "missed": fmt(d["missed_rate"], ".0%"),
        "progress": fmt(d["progress_ratio"], ".2f"),
        "disturbance": "–"
        if s.get("median_others_moved_m") is None
        else f"{100 * s['median_others_moved_m']:.1f} cm ({s['others_moved_over_1cm']:.0%} > 1 cm)",
    }


def share(x: float | None) -> str:
    """A share as a percentage ("–" for none)."""
    return "–" if x is None else f"{x:.0%}"


def diagnostics_line(s: dict) -> str:
    c, d = summary_cells(s), s["diagnostics"]
    return (
        f"phantom motion {c['phantom']} of {d['still_steps']} still steps, "
        f"missed motion {c['missed']} of {d['moved_steps']} pushes, "
        f"predicted/actual progress {c['progress']}"
    )


def _rate(s: dict[str, Any], tolerance: str) -> str:
    """A summary's success rate at a tolerance with its interval, or why it has none."""
    rate = s.get(f"success_{tolerance}")
    if rate is None:
        return "not measured (the trials stopped short of it: --tolerance)"
    lo, hi = s[f"success_{tolerance}_ci95"]
    return f"{rate:.0%}  [95 % CI {lo:.0%}-{hi:.0%}]"


def format_summary(s: dict[str, Any], title: str) -> str:
    """The printed summary of a trial set (``evaluation.trials.summarize``'s dict)."""
    return (
        f"{title}:\n"
        + "".join(
            f"  success ({metres * 100:g} cm, {degrees:g} deg)".ljust(26) + _rate(s, name) + "\n"
            for name, (metres, degrees) in TOLERANCES.items()
        )
        + f"  median final error      {s['median_final_pos_err_m'] * 100:.1f} cm, "
        f"{s['median_final_yaw_err_deg']:.1f} deg\n"
        f"  median steps            {s['median_steps']:.0f}\n"
        f"  median replan           {s['median_replan_ms_median']:.0f} ms\n"
        f"  model exploitation      {diagnostics_line(s)}\n"
        + (
            f"  path efficiency         {s['path_efficiency']:.2f} (of the distance the object "
            f"travelled, the share toward the goal)\n"
            if s.get("path_efficiency") is not None
            else ""
        )
        + (
            f"  pusher out of view      {share(s['pusher_unseen_successes'])} of the steps "
            f"of successes, {share(s['pusher_unseen_failures'])} of failures\n"
            if s.get("pusher_unseen_successes") is not None
            or s.get("pusher_unseen_failures") is not None
            else ""
        )
        + (
            f"  other objects moved     {summary_cells(s)['disturbance']} (median of the "
            f"largest displacement, {s['trials_among_others']} trials among others)\n"
            if s["trials_among_others"]
            else ""
        )
        + (
            "  by pushed object        "
            + ", ".join(
                f"{k} {v['tight']}/{v['trials']} ({v['loose']} loose)"
                for k, v in s["by_shape"].items()
            )  # fmt: skip
            + "\n"
            if len(s["by_shape"]) > 1
            else ""
        )
        + "".join(
            f"  by pushed {what:<13} "
            + ", ".join(f"{k} {v['tight']}/{v['trials']}" for k, v in s[key].items())
            + "\n"
            for what, key in (("mass", "by_mass"), ("size", "by_size"))
            if len(s[key]) > 1
        )
    ).rstrip("\n")
