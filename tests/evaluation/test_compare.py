import json

import pytest
from scipy.stats import binomtest

from evaluation.compare import mcnemar_exact, paired_difference_ci, paired_stats
from se3push.cli import main


def _outcomes(both, a_only, b_only, neither):
    """Paired outcome lists holding the given 2x2 table, the kinds interleaved."""
    kinds = [(True, True)] * both + [(True, False)] * a_only
    kinds += [(False, True)] * b_only + [(False, False)] * neither
    kinds = kinds[::2] + kinds[1::2]
    return [x for x, _ in kinds], [y for _, y in kinds]


@pytest.mark.parametrize(
    ("wins", "losses", "p"),
    [(14, 4, 0.0308838), (5, 0, 0.0625), (0, 5, 0.0625), (7, 7, 1.0), (0, 0, 1.0), (1, 0, 1.0)],
)
def test_mcnemar_matches_known_values(wins, losses, p):
    # 0.0625 = 2 / 2^5; 0.0308838 = 2 * (1 + 18 + 153 + 816 + 3060) / 2^18
    assert mcnemar_exact(wins, losses) == pytest.approx(p, abs=1e-6)


@pytest.mark.parametrize(("wins", "losses"), [(14, 4), (3, 11), (60, 41), (600, 530)])
def test_mcnemar_is_the_exact_binomial_test_of_the_discordant_pairs(wins, losses):
    expected = binomtest(wins, wins + losses, 0.5).pvalue  # an independent implementation
    assert mcnemar_exact(wins, losses) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize(
    ("table", "published"),
    [
        # Newcombe (1998) Table II, example a=20, b=12, c=2, d=16, method 10: 0.0562 to 0.3292
        # (as reproduced in the ratesci R package's tests against the paper's figures)
        ((20, 12, 2, 16), (0.0562, 0.3292)),
        # Fagerland, Lydersen & Laake (2014), airway responsiveness 1, 1, 7, 12: -0.507 to
        # -0.026 with Newcombe's correlation-corrected square-and-add (method 10)
        ((1, 1, 7, 12), (-0.507, -0.026)),
    ],
)
def test_newcombe_interval_matches_published_examples(table, published):
    lo, hi = paired_difference_ci(*table)
    digits = len(str(published[0]).split(".")[1])
    assert (round(lo, digits), round(hi, digits)) == published


def test_paired_stats_count_the_table_and_orient_the_difference_a_minus_b():
    a, b = _outcomes(20, 12, 2, 16)
    s = paired_stats(a, b)
    assert (s["n"], s["successes_a"], s["successes_b"]) == (50, 32, 22)
    assert (s["wins"], s["losses"]) == (12, 2)
    assert s["difference"] == pytest.approx(0.2)
    assert s["difference_ci95"] == pytest.approx([0.0562, 0.3292], abs=5e-5)
    assert s["p_value"] == pytest.approx(binomtest(12, 14, 0.5).pvalue)
    swapped = paired_stats(b, a)
    assert (swapped["wins"], swapped["losses"]) == (2, 12)
    assert swapped["difference_ci95"] == pytest.approx([-0.3292, -0.0562], abs=5e-5)


def test_no_discordant_pairs_give_p_one_and_an_interval_around_zero():
    s = paired_stats(*_outcomes(10, 0, 0, 10))
    assert s["p_value"] == 1.0 and s["difference"] == 0.0
    lo, hi = s["difference_ci95"]
    assert -0.3 < lo < 0 < hi < 0.3


def _write_folder(path, tight, *, loose=None, scenario="tiny", seed=0, goals=None, replan_ms=40.0,
                  config=True, log=True, disp_mm=None, objects=None):  # fmt: skip
    """A trial folder written by hand: one record per outcome, trial i's draw fixed by i."""
    path.mkdir(parents=True)
    if config:
        meta = {"scenario": scenario, "n": len(tight), "model": "m", "planner": "cem",
                "seed": seed, "max_steps": 60, "trial_set": 2}  # fmt: skip
        (path / "config.json").write_text(json.dumps(meta))
    if not log:
        return path
    lines = []
    for i, ok in enumerate(tight):
        rec = {
            "trial": i,
            "reset_seed": 1000 + i,
            "start": [0.01 * i, 0.0, 0.0],
            "goal": (goals or {}).get(i, [0.1, 0.01 * i, 0.5]),
            "success_tight": ok,
            "success_loose": ok if loose is None else loose[i],
            "final_pos_err_m": 0.01 if ok else 0.08,
            "final_yaw_err_deg": 3.0,
            "steps": 20 if ok else 60,
            "replan_ms_median": replan_ms,
        }
        if objects is not None:  # trial i pushed objects[i]
            rec["pushed_object"] = objects[i]
        if disp_mm is not None:  # every trial's steps moved the object this much
            rec["per_step"] = [{"actual_disp_m": d * 1e-3} for d in disp_mm]
        lines.append(json.dumps(rec) + "\n")
    (path / "trials.jsonl").write_text("".join(lines))
    return path


@pytest.fixture
def folders(tmp_path):
    """A wins 14, loses 4 over 50 trials (38 against 28 successes); B holds 2 more trials."""
    a, b = _outcomes(24, 14, 4, 8)
    b_folder = _write_folder(tmp_path / "B", b + [True, False], replan_ms=55.0)
    return _write_folder(tmp_path / "A", a), b_folder


def test_compare_prints_the_paired_counts_and_test(folders, capsys):
    assert main(["compare", str(folders[0]), str(folders[1])]) == 0
    out = capsys.readouterr().out
    assert "50 paired trials, tight: 2 cm & 10°" in out
    assert "success A 38/50 (76%), B 28/50 (56%); A wins 14, loses 4" in out
    assert "exact McNemar p = 0.031" in out and "difference +20 points" in out
    assert "median steps A 20, B 20; median replan A 40 ms, B 55 ms" in out


def test_compare_reports_the_median_pause_between_pushes(tmp_path, capsys):
    """A pauses 1 and 3 steps between pushes in every trial, B 6 (median 2 against 6); the
    still steps before the first push and after the last are no pause."""
    a = _write_folder(tmp_path / "A", [True] * 4, disp_mm=[0, 5, 0, 5, 0, 0, 0, 9, 0, 0])
    b = _write_folder(tmp_path / "B", [True] * 4, disp_mm=[0, 0, 5, 0.5, 0, 0, 0, 0, 0, 2])
    assert main(["compare", str(a), str(b)]) == 0
    assert "median pause between pushes A 2.0, B 6.0 steps" in capsys.readouterr().out


def test_compare_json_and_first_n(folders, capsys):
    assert main(["compare", *map(str, folders), "--n", "40", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["n"] == 40 and r["trials"] == list(range(40))
    # the first 40 of the interleaved table: 24 both, 10 A only, 2 B only, 4 neither
    assert (r["successes_a"], r["successes_b"], r["wins"], r["losses"]) == (34, 26, 10, 2)
    assert r["median_steps_a"] == 20 and r["median_replan_ms_b"] == 55


def test_compare_loose_tolerance_reads_loose_success(tmp_path, capsys):
    a = _write_folder(tmp_path / "A", [False] * 4, loose=[True] * 4)
    b = _write_folder(tmp_path / "B", [False] * 4)
    assert main(["compare", str(a), str(b), "--tolerance", "loose", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert (r["successes_a"], r["successes_b"], r["wins"]) == (4, 0, 4)
    assert r["tolerance_m_deg"] == [0.05, 20.0]


def _refused(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("error: ") and "\n" not in err
    return err


def test_a_different_goal_is_refused(tmp_path, capsys):
    a = _write_folder(tmp_path / "A", [True] * 10)
    b = _write_folder(tmp_path / "B", [False] * 10, goals={7: [0.2, 0.0, 0.0]})
    err = _refused(["compare", str(a), str(b)], capsys)
    assert "trial 7" in err and "goal" in err


def test_a_different_scenario_or_seed_is_refused(tmp_path, capsys):
    a = _write_folder(tmp_path / "A", [True] * 5)
    b = _write_folder(tmp_path / "B", [True] * 5, scenario="single_box")
    c = _write_folder(tmp_path / "C", [True] * 5, seed=1)
    assert "scenario" in _refused(["compare", str(a), str(b)], capsys)
    assert "seed" in _refused(["compare", str(a), str(c)], capsys)


def test_an_old_trial_draw_is_refused(tmp_path, capsys):
    a = _write_folder(tmp_path / "A", [True] * 5)
    b = _write_folder(tmp_path / "B", [True] * 5)
    meta = json.loads((b / "config.json").read_text())
    meta.pop("trial_set")  # written before goals were drawn with the object's symmetry
    (b / "config.json").write_text(json.dumps(meta))
    assert "trial_set" in _refused(["compare", str(a), str(b)], capsys)


def test_a_folder_without_trials_is_refused(tmp_path, capsys):
    a = _write_folder(tmp_path / "A", [True] * 5)
    b = _write_folder(tmp_path / "B", [True] * 5, log=False)
    assert "trials.jsonl" in _refused(["compare", str(a), str(b)], capsys)
    assert "trials.jsonl" in _refused(["compare", str(a), str(tmp_path / "nowhere")], capsys)


def test_more_trials_than_a_folder_holds_are_refused(folders, capsys):
    err = _refused(["compare", *map(str, folders), "--n", "51"], capsys)
    assert "holds 50 of the first 51" in err


def test_pairs_of_folders_are_compared_each_and_pooled_in_one_test(folders, tmp_path, capsys):
    """A second pair of another scenario and seed: A wins 1 and loses 2 of 3, so over both
    pairs A wins 15 and loses 6 of 53, tested once on all of them."""
    a2 = _write_folder(tmp_path / "A2", [True, False, False], scenario="single_box", seed=1)
    b2 = _write_folder(tmp_path / "B2", [False, True, True], scenario="single_box", seed=1)
    argv = ["compare", *map(str, folders), "--pair", str(a2), str(b2)]
    assert main([*argv, "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert [(c["wins"], c["losses"]) for c in r["comparisons"]] == [(14, 4), (1, 2)]
    pooled = r["pooled"]
    assert (pooled["pairs"], pooled["n"], pooled["wins"], pooled["losses"]) == (2, 53, 15, 6)
    assert (pooled["successes_a"], pooled["successes_b"]) == (39, 30)
    assert pooled["p_value"] == pytest.approx(mcnemar_exact(15, 6))
    assert pooled["p_value"] > r["comparisons"][0]["p_value"]  # 15/6 is weaker than 14/4
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "pooled over 2 pairs of folders (53 paired trials, tight" in out
    assert "success A 39/53 (74%), B 30/53 (57%); A wins 15, loses 6" in out


BOX_BIG = {"shape": "box", "size_m": [0.124, 0.093, 0.06], "mass_kg": 0.65}
BOX_SMALL = {"shape": "box", "size_m": [0.105, 0.09, 0.06], "mass_kg": 0.55}
TEE = {"shape": "T", "size_m": [0.085, 0.09, 0.05], "mass_kg": 0.55}


def test_compare_by_the_pushed_object_splits_the_paired_trials_into_groups(tmp_path, capsys):
    """A loses the three big boxes and wins two of the four T-shapes: the groups say where,
    the whole set (2 wins, 3 losses) does not; pooled over two pairs, the groups pool too."""
    objects = [BOX_BIG] * 3 + [TEE] * 4 + [BOX_SMALL]
    tight_a = [False] * 3 + [True, True, False, True, True]
    tight_b = [True] * 3 + [False, False, False, True, True]
    a = _write_folder(tmp_path / "A", tight_a, objects=objects)
    b = _write_folder(tmp_path / "B", tight_b, objects=objects)
    assert main(["compare", str(a), str(b), "--by", "shape", "size", "--json"]) == 0
    groups = json.loads(capsys.readouterr().out)["groups"]
    assert list(groups) == ["T 8-10 cm", "box 10-12 cm", "box 12-14 cm"]
    t, small, big = groups.values()
    assert (t["n"], t["wins"], t["losses"], t["successes_a"]) == (4, 2, 0, 3)
    assert (big["n"], big["wins"], big["losses"], big["successes_b"]) == (3, 0, 3, 3)
    assert (small["n"], small["wins"], small["losses"]) == (1, 0, 0)
    assert main(["compare", str(a), str(b), "--by", "mass", "--pair", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    pooled = out[out.index("pooled") :]
    assert "  0.5-0.6 kg: success A 8/10 (80%), B 4/10 (40%); A wins 4, loses 0" in pooled
    assert "  0.6-0.7 kg: success A 0/6 (0%), B 6/6 (100%); A wins 0, loses 6" in pooled


def test_compare_by_needs_records_that_say_what_they_pushed(folders, capsys):
    err = _refused(["compare", *map(str, folders), "--by", "shape"], capsys)
    assert "pushed_object" in err and "trial 0" in err
    assert "--by takes shape, size, mass; got colour" in _refused(
        ["compare", *map(str, folders), "--by", "colour"], capsys
    )


def test_a_damaged_folder_is_refused_in_one_line(folders, capsys):
    a, b = folders
    (a / "config.json").write_text('{"scenario": "single_box", "seed": 0')  # cut
    assert main(["compare", str(a), str(b)]) == 2
    assert "config.json is not a trials configuration" in capsys.readouterr().err
    (b / "trials.jsonl").write_text("7\n")
    assert main(["compare", str(b), str(b)]) == 2
    assert "a line is not a trial record" in capsys.readouterr().err


def _edit_first_record(folder, **changes):
    lines = (folder / "trials.jsonl").read_text().splitlines()
    first = json.loads(lines[0])
    for key, value in changes.items():
        if value is None:
            first.pop(key)
        else:
            first[key] = value
    (folder / "trials.jsonl").write_text("\n".join([json.dumps(first), *lines[1:]]) + "\n")


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda a: (a / "trials.jsonl").write_bytes(b"\xff\xfe"), "trials.jsonl is not UTF-8 text"),
        (lambda a: _edit_first_record(a, trial=[0]),
         "a record's trial is [0], not a trial's number"),
        (lambda a: _edit_first_record(a, success_tight="yes"),
         "a record's success_tight is 'yes', not true or false"),
        (lambda a: (a / "config.json").write_text(json.dumps(
            {**json.loads((a / "config.json").read_text()), "tolerance": "precise"})),
         "config.json is not a trials configuration"),
        (lambda a: _edit_first_record(a, pushed_object={"mass_kg": 0.3}),
         "trial 0's pushed_object ({'mass_kg': 0.3}) lacks what --by shape groups by"),
    ],
)  # fmt: skip
def test_an_edited_log_is_refused_in_one_line(folders, capsys, damage, message):
    a, b = folders
    damage(a)
    assert main(["compare", str(a), str(b), "--by", "shape"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_a_record_without_a_success_its_config_measured_is_refused(folders, capsys):
    a, b = folders
    for folder in (a, b):  # both ran on to 1 cm and 5 deg, but A's first record lost it
        meta = json.loads((folder / "config.json").read_text())
        (folder / "config.json").write_text(json.dumps({**meta, "tolerance": [0.01, 5.0]}))
        lines = [json.loads(x) for x in (folder / "trials.jsonl").read_text().splitlines()]
        (folder / "trials.jsonl").write_text(
            "".join(json.dumps({**r, "success_precise": r["success_tight"]}) + "\n" for r in lines)
        )
    _edit_first_record(a, success_precise=None)
    assert main(["compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert "trial 0's record lacks success_precise, which its config.json says was measured" in err
