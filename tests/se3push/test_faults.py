"""Fault injection: the commands that write folders are SIGKILLed at random (seeded) moments,
run again until they finish, and must end with what an uninterrupted run writes (bytes for data;
every tensor and field of a checkpoint, which holds no wall clock; records but their wall-clock
fields for trials, training metrics and improve; a record naming the run's own folder reads the
same), leave no process of theirs alive, and refuse a second writer of their folder.

The fast variant (3 kills) is in the default suite; the slow one (24 kills, 6 a command) gives
the README's reliability figures: ``python -m pytest -m slow tests/se3push/test_faults.py -s``.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from sim.folders import LOCK_NAME

WALL_CLOCK = ("replan_ms", "elapsed_s", "model_sha256")
"""keys (or parts of keys) of figures that time the machine, not the computation; and the
hash of a checkpoint file, which records its data folders by name (those of the run's own
folder differ between the runs compared; the checkpoints themselves are compared field by
field)"""


def _command(name: str, root: Path, out: Path) -> list[str]:
    """Tiny settings of each command, writing ``out`` (data and the model come from the
    reference runs in ``root``)."""
    workers = ["--workers", "2"]
    return {
        "data": ["data", "--scenario", "tiny", "--episodes", "200", "--steps-per-episode", "8",
                 *workers, "--out", str(out)],
        "train": ["train", "--data", str(root / "ref_data"), "--iters", "40", "--batch", "4",
                  "--eval-every", "5", "--k", "3", "--out", str(out)],
        "trials": ["trials", "--scenario", "tiny", "--n", "24", "--model", "no-motion",
                   "--max-steps", "60", *workers, "--out", str(out)],
        "improve": ["improve", "--scenario", "tiny", "--model", str(root / "ref_train" / "best.pt"),
                    "--data", str(root / "ref_data"), "--rounds", "1", "--trials-per-round", "2",
                    "--heldout", "2", "--max-steps", "3", "--finetune-iters", "4", *workers,
                    "--out", str(out)],
    }[name]  # fmt: skip


COMMANDS = ("data", "train", "trials", "improve")
"""in the order they run: train reads the reference data, improve the reference model"""


def _start(argv: list[str], log: Path) -> subprocess.Popen:
    """``se3push argv`` in a session of its own (so that what it leaves behind can be found)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    with open(log, "ab") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "se3push.cli", *argv], stdout=f, stderr=f, env=env,
            start_new_session=True, cwd=log.parent,
        )  # fmt: skip


def _alive_in_session(sid: int) -> list[int]:
    """Processes of session ``sid`` that are alive (not zombies waiting to be reaped)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2 :].split()
        if int(fields[3]) == sid and fields[0] != "Z":
            pids.append(int(stat.parent.name))
    return pids


def _left_alive(sid: int, wait_s: float = 5.0) -> list[int]:
    """Processes of session ``sid`` still alive after ``wait_s`` seconds of grace."""
    end = time.monotonic() + wait_s
    while (pids := _alive_in_session(sid)) and time.monotonic() < end:
        time.sleep(0.05)
    return pids


def _finish(name: str, root: Path, out: Path, log: Path) -> None:
    argv = _command(name, root, out)
    if name == "train" and (out / "last.pt").exists():
        argv.append("--resume")
    proc = _start(argv, log)
    try:
        assert proc.wait(timeout=300) == 0, log.read_text()[-3000:]
    finally:
        _kill_session(proc.pid)


def _kill_session(sid: int) -> None:
    """Clean-up whatever the test's outcome: nothing of a run outlives the test."""
    try:
        os.killpg(sid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def _strip(obj, out: Path):
    """``obj`` without its wall-clock figures, and with the run's own folder (which a record
    may name, absolute or relative, and which differs between the runs compared) as ``OUT``."""
    if isinstance(obj, dict):
        timed = {k for k in obj if isinstance(k, str) and any(w in k for w in WALL_CLOCK)}
        return {k: _strip(v, out) for k, v in obj.items() if k not in timed}
    if isinstance(obj, list):
        return [_strip(v, out) for v in obj]
    if isinstance(obj, str):  # the folder as given, or relative to the run's directory
        return re.sub(rf"(^|/){re.escape(out.name)}(/|$)", r"\1OUT\2", obj.replace(str(out), "OUT"))
    if isinstance(obj, torch.Tensor):
        return (obj.dtype, tuple(obj.shape), obj.numpy().tobytes())
    if isinstance(obj, tuple):
        return tuple(_strip(v, out) for v in obj)
    return obj


def _outputs(name: str, out: Path) -> dict[str, object]:
    """What a finished run wrote, in the form two runs must agree on."""
    found: dict[str, object] = {}
    for path in sorted(p for p in out.rglob("*") if p.is_file()):
        rel = str(path.relative_to(out))
        if path.name == LOCK_NAME or path.suffix in (".png", ".md"):
            continue  # the lock holds a pid; pictures and tables are drawn from the records
        if path.suffix == ".pt":  # every byte of it but the run folder's name in its config
            found[rel] = _strip(torch.load(path, map_location="cpu", weights_only=False), out)
        elif path.suffix == ".jsonl":
            found[rel] = [_strip(json.loads(x), out) for x in path.read_text().splitlines()]
        elif path.suffix == ".json":
            found[rel] = _strip(json.loads(path.read_text()), out)
        else:
            found[rel] = path.read_bytes()
    assert found, f"{name} wrote nothing to {out}"
    return found


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """Uninterrupted runs of every command: their outputs and wall times."""
    root = tmp_path_factory.mktemp("faults")
    refs = {}
    for name in COMMANDS:
        t0 = time.monotonic()
        _finish(name, root, root / f"ref_{name}", root / f"ref_{name}.log")
        refs[name] = (_outputs(name, root / f"ref_{name}"), time.monotonic() - t0)
    return root, refs


def _second_writer_is_refused(name: str, root: Path, out: Path, first: subprocess.Popen) -> None:
    """While ``first`` writes ``out``, the same command on ``out`` is refused at once, exit 2,
    naming ``first``'s process."""
    end = time.monotonic() + 60
    while not (out / LOCK_NAME).exists() or not (out / LOCK_NAME).read_text():
        assert first.poll() is None, "the first run ended before it took its folder"
        assert time.monotonic() < end
        time.sleep(0.02)
    first.send_signal(signal.SIGSTOP)  # it holds the folder, however fast it would finish
    try:
        second = subprocess.run(
            [sys.executable, "-m", "se3push.cli", *_command(name, root, out)],
            capture_output=True, text=True, timeout=60,
            env={**os.environ, "OMP_NUM_THREADS": "1"}, cwd=root,
        )  # fmt: skip
    finally:
        first.send_signal(signal.SIGCONT)
    assert second.returncode == 2, second.stderr
    err = second.stderr.strip().splitlines()
    assert len(err) == 1 and f"process {first.pid}" in err[0] and str(out) in err[0], err


@pytest.mark.parametrize(
    "kills", [pytest.param(3, id="fast"), pytest.param(24, id="slow", marks=pytest.mark.slow)]
)
def test_random_kills_resume_to_the_uninterrupted_outputs_and_leave_no_process(references, kills):
    root, refs = references
    rng = np.random.default_rng(kills)
    tally = {name: {"kills": 0, "identical": 0, "left_alive": 0} for name in COMMANDS}
    for i in range(kills):
        name = COMMANDS[i % len(COMMANDS)]
        out = root / f"killed_{kills}_{i}"
        log = root / f"killed_{kills}_{i}.log"
        argv = _command(name, root, out)
        # a moment within the uninterrupted run's wall time, after the imports
        kill_at = time.monotonic() + rng.uniform(0.4, 0.95) * refs[name][1]
        proc = _start(argv, log)
        try:
            if i < len(COMMANDS):  # the first run of each command also meets a second writer
                _second_writer_is_refused(name, root, out, proc)
            time.sleep(max(0.0, kill_at - time.monotonic()))
            killed = proc.poll() is None
            proc.send_signal(signal.SIGKILL)  # the parent alone: its workers must follow
            proc.wait()
            left = _left_alive(proc.pid)
            tally[name]["left_alive"] += len(left)
            assert not left, f"{name}: processes {left} outlived their command"
        finally:
            _kill_session(proc.pid)
        _finish(name, root, out, log)
        assert _outputs(name, out) == refs[name][0], f"{name}: resumed outputs differ"
        tally[name]["kills"] += killed
        tally[name]["identical"] += killed
    print("\nfault injection:", json.dumps(tally))
    assert sum(t["kills"] for t in tally.values()) >= kills // 2  # most kills landed mid-run
