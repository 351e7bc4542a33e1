"""Paired comparison of two trial folders: which planner or model succeeds more often.

Two folders written by ``se3push trials`` with the same scenario, seed and trial draw hold the
same trials (see evaluation/trials.py), so their outcomes pair by trial index. Trials that both
succeed or both fail say nothing about which is better; the discordant pairs do. The
statistics are the exact McNemar test on those pairs and Newcombe's (1998) interval for the
paired difference of success rates. Computing returns data; :func:`format_comparison` prints.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.diagnostics import pauses
from evaluation.records import migrate_config, migrate_record
from evaluation.report import fmt
from evaluation.trials import GROUPINGS, label_order, same_trial, wilson
from planner.loop import TIGHT, TOLERANCES
from scenarios import InputError
from scenarios.config import differences

SAME_TRIAL_KEYS = ("reset_seed", "start", "goal")
"""what makes two records the same trial"""
RECORD_KEYS = ("trial", *SAME_TRIAL_KEYS, "success_tight", "success_loose")
"""keys every trial record must have to be compared"""


def mcnemar_exact(wins: int, losses: int) -> float:
    """Exact two-sided McNemar p-value: a binomial test of the discordant pairs at 1/2.

    Args:
        wins: pairs where A succeeded and B failed.
        losses: pairs where A failed and B succeeded.

    Returns:
        ``min(1, 2 * sum_{i <= min(w, l)} C(w + l, i) / 2^(w + l))``; 1 when there are no
        discordant pairs.
    """
    m = wins + losses
    tail = sum(math.comb(m, i) for i in range(min(wins, losses) + 1))
    return min(1.0, 2 * tail / 2**m)  # exact integers until the one division


def paired_difference_ci(
    both: int, a_only: int, b_only: int, neither: int, *, z: float = 1.96
) -> tuple[float, float]:
    """Interval of the paired difference of success rates p_A - p_B: Newcombe (1998) method 10.

    Newcombe, "Improved confidence intervals for the difference between binomial proportions
    based on paired data", Stat. Med. 17:2635-2650, method 10 (the hybrid score interval):
    with ``n = both + a_only + b_only + neither``, the rates ``p1 = (both + a_only) / n`` and
    ``p2 = (both + b_only) / n`` have Wilson intervals (l1, u1) and (l2, u2), and

        L = (p1 - p2) - sqrt((p1 - l1)^2 - 2 phi (p1 - l1)(u2 - p2) + (u2 - p2)^2)
        U = (p1 - p2) + sqrt((u1 - p1)^2 - 2 phi (u1 - p1)(p2 - l2) + (p2 - l2)^2)

    where phi is the correlation of the two outcomes, ``C / sqrt(e f g h)`` over the four
    margins e, f, g, h, with Newcombe's continuity correction of ``D = both * neither -
    a_only * b_only``: C = D - n/2 if D > n/2, 0 if 0 <= D <= n/2, D if D < 0 (phi = 0 when a
    margin is empty).

    Args:
        both, a_only, b_only, neither: counts of the paired 2x2 table (n >= 1).
        z: normal quantile of the interval (1.96: 95 %).

    Returns:
        (lower, upper) of p_A - p_B.
    """
    n = both + a_only + b_only + neither
    p1, p2 = (both + a_only) / n, (both + b_only) / n
    (l1, u1), (l2, u2) = wilson(both + a_only, n, z), wilson(both + b_only, n, z)
    margins = (both + a_only) * (b_only + neither) * (both + b_only) * (a_only + neither)
    d = both * neither - a_only * b_only
    c = d - n / 2 if d > n / 2 else min(d, 0)
    phi = c / math.sqrt(margins) if margins else 0.0
    lower = math.sqrt(max(0.0, (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    upper = math.sqrt(max(0.0, (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2))
    return p1 - p2 - lower, p1 - p2 + upper


def paired_stats(success_a: Sequence[bool], success_b: Sequence[bool]) -> dict[str, Any]:
    """Statistics of paired outcomes: trial i of A against trial i of B.

    Args:
        success_a, success_b: outcomes (N,), at least one, paired by position.

    Returns:
        ``n``, ``successes_a``, ``successes_b``, ``wins`` (A succeeded, B failed), ``losses``
        (A failed, B succeeded), ``p_value`` (exact McNemar), ``difference`` (success rate of
        A minus B) and ``difference_ci95`` ([lower, upper], Newcombe method 10).
    """
    if len(success_a) != len(success_b) or len(success_a) == 0:
        raise ValueError(f"need paired outcomes, got {len(success_a)} and {len(success_b)}")
    pairs = [(bool(x), bool(y)) for x, y in zip(success_a, success_b, strict=True)]
    both, wins = pairs.count((True, True)), pairs.count((True, False))
    losses, neither = pairs.count((False, True)), pairs.count((False, False))
    n = len(pairs)
    return {
        "n": n,
        "successes_a": both + wins,
        "successes_b": both + losses,
        "wins": wins,
        "losses": losses,
        "p_value": mcnemar_exact(wins, losses),
        "difference": (wins - losses) / n,
        "difference_ci95": list(paired_difference_ci(both, wins, losses, neither)),
    }


def read_trials(folder: str | Path) -> tuple[dict[str, Any], dict[int, dict[str, Any]]]:
    """A trial folder's ``config.json`` and its finished trials, by trial index.

    Raises:
        InputError: the folder lacks ``config.json`` or ``trials.jsonl``, or a record lacks a
            key comparison needs.
    """
    folder = Path(folder)
    meta, log = folder / "config.json", folder / "trials.jsonl"
    for path in (log, meta):
        if not path.is_file():
            raise InputError(
                f"{folder} has no {path.name}: give a folder written by `se3push trials --out`"
            )

    def text(path: Path) -> str:
        try:
            return path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{path} is not UTF-8 text; is it a trial folder's?") from None

    records = {}
    for line in text(log).splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue  # a blank line, or one cut by an interruption: that trial is unfinished
        if not isinstance(rec, dict):
            raise InputError(f"{log}: a line is not a trial record; is it a trial log?")
        missing = [k for k in RECORD_KEYS if k not in rec]
        if missing:
            raise InputError(f"{log}: a record lacks {', '.join(missing)}; is it a trial log?")
        if type(rec["trial"]) is not int:
            raise InputError(f"{log}: a record's trial is {rec['trial']!r}, not a trial's "
                             "number; was the log edited?")  # fmt: skip
        odd = [k for k in RECORD_KEYS if k.startswith("success_") and type(rec[k]) is not bool]
        if odd:
            raise InputError(f"{log}: a record's {odd[0]} is {rec[odd[0]]!r}, not true or "
                             "false; was the log edited?")  # fmt: skip
        records[rec["trial"]] = migrate_record(rec)
    try:
        config = json.loads(text(meta))
    except json.JSONDecodeError:
        config = None
    if not isinstance(config, dict) or not _tolerance_ok(config.get("tolerance", TIGHT)):
        raise InputError(f"{meta} is not a trials configuration (cut or edited?); run the "
                         "folder's `se3push trials` command again to rewrite it")  # fmt: skip
    return config, records


def _tolerance_ok(tolerance: Any) -> bool:
    """Whether a configuration's ``tolerance`` is a position (m) and a yaw (deg)."""
    return (
        isinstance(tolerance, list | tuple)
        and len(tolerance) == 2
        and all(isinstance(x, int | float) and not isinstance(x, bool) for x in tolerance)
    )


def _draw(config: dict[str, Any]) -> dict[str, Any]:
    """What fixes a folder's trial set (a folder without ``trial_set`` predates version 2)."""
    return {k: config.get(k) for k in ("scenario", "seed")} | {
        "trial_set": config.get("trial_set", 1)
    }


def compare_trials(
    a: str | Path,
    b: str | Path,
    *,
    tolerance: str = "tight",
    n: int | None = None,
    by: Sequence[str] = (),
) -> dict[str, Any]:
    """Compare two trial folders pair by pair over the trials both hold, or the first ``n``.

    Args:
        a, b: folders written by ``se3push trials --out`` with the same scenario and seed.
        tolerance: "precise" (1 cm, 5°; only folders whose trials ran on to it), "tight"
            (2 cm, 10°) or "loose" (5 cm, 20°) success.
        n: compare trials 0..n-1 (both folders must hold them); None: every trial both hold.
        by: names of :data:`evaluation.trials.GROUPINGS` (``shape``, ``size``, ``mass``): the
            paired trials are also compared group by group of their pushed object (one group
            per combination of the named keys), in ``groups``.

    Returns:
        :func:`paired_stats` of the outcomes, plus ``a``, ``b`` (folders), ``tolerance``,
        ``tolerance_m_deg``, ``trials`` (the paired indices), ``outcomes_a`` and
        ``outcomes_b`` (success per paired trial), ``by_tolerance`` (the successes, wins,
        losses and p at every tolerance both folders measured) and per folder the medians over
        those trials of ``steps`` and ``replan_ms_median`` (``median_steps_a``,
        ``median_replan_ms_a``, ... ; None where a record lacks the figure), and the median
        of their pauses between pushes (``median_pause_a``: ``planner.diagnostics.pauses``;
        None where a record lacks ``per_step`` or no trial paused).

    Raises:
        InputError: a folder is not a trial folder, the two hold different trials, they share
            none, a folder lacks one of the first ``n``, a bad ``tolerance``, ``n`` or ``by``,
            or ``by`` with records that do not say what they pushed.
    """
    unknown = [k for k in by if k not in GROUPINGS]
    if unknown:
        raise InputError(f"--by takes {', '.join(GROUPINGS)}; got {', '.join(unknown)}")
    if tolerance not in TOLERANCES:
        raise InputError(f"--tolerance must be one of {', '.join(TOLERANCES)}, got {tolerance!r}")
    if n is not None and n < 1:
        raise InputError(f"--n must be positive, got {n}")
    (config_a, recs_a), (config_b, recs_b) = read_trials(a), read_trials(b)
    drawn = differences(_draw(config_a), _draw(config_b), old_has="A has", new_has="B has")
    if drawn:
        raise InputError(
            f"{a} and {b} hold different trial sets ({'; '.join(drawn)}); compare folders run "
            "with the same --scenario and --seed (and the same trial_set: rerun the older one)"
        )
    if n is None:
        trials = sorted(recs_a.keys() & recs_b.keys())
        if not trials:
            raise InputError(f"{a} and {b} share no finished trials; run both with --n")
    else:
        trials = list(range(n))
        for folder, recs in ((a, recs_a), (b, recs_b)):
            held = sum(i in recs for i in trials)
            if held < n:
                raise InputError(
                    f"{folder} holds {held} of the first {n} trials; finish it with "
                    f"`se3push trials --n {n} --out {folder}` (same settings) or ask for less --n"
                )
    unlike = [i for i in trials if not same_trial(recs_a[i], recs_b[i])]
    if unlike:
        i = unlike[0]
        ka, kb = ({k: recs[i][k] for k in SAME_TRIAL_KEYS} for recs in (recs_a, recs_b))
        raise InputError(
            f"{a} and {b} hold different trials ({len(unlike)} of {len(trials)} differ; trial "
            f"{i}: {'; '.join(differences(ka, kb, old_has='A has', new_has='B has'))}); "
            "compare folders run with the same --scenario, --seed and trial draw"
        )
    measured = [
        name for name in TOLERANCES if all(_measures(c, name) for c in (config_a, config_b))
    ]
    if tolerance not in measured:
        folder = a if not _measures(config_a, tolerance) else b
        raise InputError(
            f"{folder} ran its trials to a looser tolerance than {tolerance}, so it does not "
            f"measure that success; run them with `se3push trials --tolerance {tolerance}`"
        )

    for folder, recs in ((a, recs_a), (b, recs_b)):
        for i in trials:
            lacking = [name for name in measured if f"success_{name}" not in recs[i]]
            if lacking:
                raise InputError(
                    f"{folder}: trial {i}'s record lacks success_{lacking[0]}, which its "
                    "config.json says was measured; was the log edited?"
                )

    def outcomes(name: str) -> tuple[list[bool], list[bool]]:
        key = f"success_{name}"
        return tuple([bool(recs[i][key]) for i in trials] for recs in (recs_a, recs_b))

    outcomes_a, outcomes_b = outcomes(tolerance)
    out = {"a": str(a), "b": str(b), "tolerance": tolerance}
    out |= {"tolerance_m_deg": list(TOLERANCES[tolerance]), "trials": trials}
    out |= {"outcomes_a": outcomes_a, "outcomes_b": outcomes_b}
    out |= paired_stats(outcomes_a, outcomes_b)
    out["by_tolerance"] = {name: paired_stats(*outcomes(name)) for name in measured}
    for side, recs in (("a", recs_a), ("b", recs_b)):
        out[f"median_steps_{side}"] = _median([recs[i].get("steps") for i in trials])
        out[f"median_replan_ms_{side}"] = _median([recs[i].get("replan_ms_median") for i in trials])
        out[f"median_pause_{side}"] = _median_pause([recs[i].get("per_step") for i in trials])
    if by:
        out["groups"] = _groups(recs_a, trials, outcomes_a, outcomes_b, by, folder=a)
    return out


def _measures(config: dict[str, Any], tolerance: str) -> bool:
    """Whether a folder's trials ran on until within ``tolerance`` (or a tighter one), so that
    their success at it is measured (folders from before the setting ran to tight)."""
    pos, yaw = migrate_config(config).get("tolerance", TIGHT)
    limit = TOLERANCES[tolerance]
    return pos <= limit[0] and yaw <= limit[1]


def _groups(
    recs: dict[int, dict[str, Any]],
    trials: list[int],
    outcomes_a: list[bool],
    outcomes_b: list[bool],
    by: Sequence[str],
    *,
    folder: str | Path,
) -> dict[str, dict[str, Any]]:
    """The paired outcomes grouped by the pushed object (the same in both folders: a trial is
    its world's reset seed), each group's ``outcomes_a``, ``outcomes_b`` and
    :func:`paired_stats`, in the order of :func:`evaluation.trials.label_order`."""
    split: dict[str, tuple[list[bool], list[bool]]] = {}
    for i, x, y in zip(trials, outcomes_a, outcomes_b, strict=True):
        obj = recs[i].get("pushed_object")
        if not obj:
            raise InputError(
                f"{folder}: trial {i}'s record does not say what it pushed (a record from "
                "before pushed_object was kept); --by needs it: rerun the folder's trials"
            )
        try:
            label = " ".join(GROUPINGS[k](obj) for k in by)
        except (KeyError, TypeError, ValueError):
            raise InputError(
                f"{folder}: trial {i}'s pushed_object ({obj!r}) lacks what --by "
                f"{' '.join(by)} groups by; was the log edited?"
            ) from None
        xs, ys = split.setdefault(label, ([], []))
        xs.append(x)
        ys.append(y)
    return {
        label: _group(xs, ys)
        for label, (xs, ys) in sorted(split.items(), key=lambda item: label_order(item[0]))
    }


def _group(outcomes_a: list[bool], outcomes_b: list[bool]) -> dict[str, Any]:
    """One group of a grouped comparison: its paired outcomes (to pool) and their
    :func:`paired_stats`."""
    return {
        "outcomes_a": outcomes_a,
        "outcomes_b": outcomes_b,
        **paired_stats(outcomes_a, outcomes_b),
    }


def _median_pause(per_step: list[list[dict] | None]) -> float | None:
    """Median pause between pushes over trials' ``per_step`` records (None: a record lacks
    them, or nothing paused)."""
    if None in per_step:
        return None
    every = [p for steps in per_step for p in pauses([s["actual_disp_m"] for s in steps])]
    return float(np.median(every)) if every else None


def _median(values: list[float | None]) -> float | None:
    """Median, or None where a record lacks the figure."""
    return None if None in values else float(np.median(values))


def pool_comparisons(comparisons: list[dict[str, Any]]) -> dict[str, Any]:
    """Several :func:`compare_trials` results (one per scenario, say) as one paired test
    over all their trials: :func:`paired_stats` of the outcomes put end to end, plus
    ``pairs`` (how many comparisons), ``tolerance`` and ``tolerance_m_deg``.

    Raises:
        ValueError: the comparisons were made at different tolerances (a caller's bug: the
            command line has one ``--tolerance`` for every pair).
    """
    tolerances = {c["tolerance"] for c in comparisons}
    if len(tolerances) != 1:
        raise ValueError(f"cannot pool comparisons at different tolerances: {sorted(tolerances)}")
    first = comparisons[0]
    out = {
        "pairs": len(comparisons),
        "tolerance": first["tolerance"],
        "tolerance_m_deg": first["tolerance_m_deg"],
        **paired_stats(
            [x for c in comparisons for x in c["outcomes_a"]],
            [x for c in comparisons for x in c["outcomes_b"]],
        ),
    }
    if all("groups" in c for c in comparisons):
        labels = sorted({label for c in comparisons for label in c["groups"]}, key=label_order)
        out["groups"] = {}
        for label in labels:
            parts = [c["groups"][label] for c in comparisons if label in c["groups"]]
            xs = [x for g in parts for x in g["outcomes_a"]]
            ys = [y for g in parts for y in g["outcomes_b"]]
            out["groups"][label] = _group(xs, ys)
    return out


def _scope(c: dict[str, Any]) -> str:
    """How many paired trials, at which tolerance: ``"50 paired trials, tight: 2 cm & 10°"``."""
    metres, degrees = c["tolerance_m_deg"]
    return f"{c['n']} paired trials, {c['tolerance']}: {metres * 100:g} cm & {degrees:g}°"


def _success_line(c: dict[str, Any]) -> str:
    """Successes, wins and losses, the exact McNemar test and the difference's interval."""
    n, (lo, hi), p = c["n"], c["difference_ci95"], c["p_value"]
    p_text = "p < 0.001" if p < 0.001 else f"p = {p:.2g}"
    return (
        f"success A {c['successes_a']}/{n} ({c['successes_a'] / n:.0%}), "
        f"B {c['successes_b']}/{n} ({c['successes_b'] / n:.0%}); "
        f"A wins {c['wins']}, loses {c['losses']}; exact McNemar {p_text}; "
        f"difference {c['difference'] * 100:+.0f} points "
        f"[95 % CI {lo * 100:+.0f} to {hi * 100:+.0f}]"
    )


def _group_lines(c: dict[str, Any]) -> list[str]:
    """A line per group of a comparison made with ``by`` (none without)."""
    return [f"  {label}: {_success_line(g)}" for label, g in c.get("groups", {}).items()]


def format_pooled(pooled: dict[str, Any]) -> str:
    """Two lines of a :func:`pool_comparisons` result, for the terminal, and a line per group
    where the comparisons were grouped."""
    head = f"pooled over {pooled['pairs']} pairs of folders ({_scope(pooled)})"
    return "\n".join([head, _success_line(pooled), *_group_lines(pooled)])


def format_comparison(c: dict[str, Any]) -> str:
    """Three lines of a :func:`compare_trials` result, for the terminal."""
    lines = [f"A: {c['a']}  B: {c['b']}  ({_scope(c)})", _success_line(c)]
    for name, t in c.get("by_tolerance", {}).items():
        if name != c["tolerance"]:
            metres, degrees = TOLERANCES[name]
            lines.append(f"  at {name} ({metres * 100:g} cm & {degrees:g}°): {_success_line(t)}")
    lines.append(
        f"median steps A {fmt(c['median_steps_a'], '.0f')}, B {fmt(c['median_steps_b'], '.0f')}; "
        f"median replan A {fmt(c['median_replan_ms_a'], '.0f')} ms, "
        f"B {fmt(c['median_replan_ms_b'], '.0f')} ms; "
        f"median pause between pushes A {fmt(c['median_pause_a'], '.1f')}, "
        f"B {fmt(c['median_pause_b'], '.1f')} steps"
    )
    return "\n".join(lines + _group_lines(c))
