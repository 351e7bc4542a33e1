"""Output folders: one writer, a clear word on a folder that cannot be written, no partial
file left behind, and Ctrl-C that stops a pool at once."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from se3push.cli import main
from sim import shards
from sim.folders import LOCK_NAME, exclusive
from sim.shards import sha256


@pytest.fixture
def mount(tmp_path):
    """``mount(size, read_only)``: a tmpfs folder of ``size`` (root only; skipped elsewhere)."""
    mounted = []

    def make(size: str, *, read_only: bool = False) -> Path:
        where = tmp_path / f"mnt{len(mounted)}"
        where.mkdir()
        opts = f"size={size}" + (",ro" if read_only else "")
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(where)],
                              capture_output=True)  # fmt: skip
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
        mounted.append(where)
        return where

    yield make
    for where in mounted:
        subprocess.run(["umount", "-l", str(where)], check=False)


def _data_args(out: Path, episodes: int = 40) -> list[str]:
    return ["data", "--scenario", "tiny", "--episodes", str(episodes), "--steps-per-episode", "8",
            "--out", str(out)]  # fmt: skip


def _one_line(capsys) -> str:
    lines = capsys.readouterr().err.replace("\r", "\n").splitlines()  # tqdm's bar ends in \r
    err = [ln[ln.index("error:") :] for ln in lines if "error:" in ln]
    assert len(err) == 1, err
    return err[0]


def test_a_folder_this_process_holds_can_be_held_again_and_is_released(tmp_path):
    with exclusive(tmp_path / "a"), exclusive(tmp_path / "a"):
        pass
    with exclusive(tmp_path / "a"):  # released: taken again
        assert (tmp_path / "a" / LOCK_NAME).read_text().split("\n")[0] == str(os.getpid())


def test_a_refused_command_leaves_no_folder_behind(tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "r")]) == 2
    assert not (tmp_path / "r").exists()


def test_a_read_only_folder_is_refused_in_one_line_naming_it(mount, capsys):
    ro = mount("1m", read_only=True)
    out = ro / "d"
    assert main(_data_args(out)) == 2
    line = _one_line(capsys)
    assert str(out) in line and "read-only" in line.lower()


def test_a_full_disk_is_refused_in_one_line_and_leaves_no_partial_file(mount, capsys):
    full = mount("150k")
    out = full / "d"
    assert main(_data_args(out, episodes=200)) == 2
    line = _one_line(capsys)
    assert str(out) in line and "no space" in line
    names = [p.name for p in out.iterdir()]
    assert not [n for n in names if ".tmp-" in n]
    manifest = json.loads((out / "manifest.json").read_text())
    assert not manifest["complete"]  # and every shard it lists is whole
    for name, entry in manifest["shards"].items():
        assert sha256(out / name) == entry["sha256"]


def test_a_write_that_fails_leaves_no_temporary_file_and_exits_2(tmp_path, capsys, monkeypatch):
    """Where no tmpfs can be mounted: the disk fills at the first shard's fsync."""

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(shards.os, "fsync", full)
    out = tmp_path / "d"
    assert main(_data_args(out)) == 2
    line = _one_line(capsys)
    assert str(out) in line and "no space" in line
    assert not list(tmp_path.rglob("*.tmp-*"))


def test_ctrl_c_stops_a_pool_at_once_with_one_line_and_exit_130(tmp_path):
    out = tmp_path / "t"
    proc = subprocess.Popen(
        [sys.executable, "-m", "se3push.cli", "trials", "--scenario", "tiny", "--n", "200",
         "--model", "no-motion", "--max-steps", "60", "--workers", "2", "--out", str(out)],
        stderr=subprocess.PIPE, text=True, start_new_session=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    try:
        end = time.monotonic() + 60
        while not (out / "trials.jsonl").exists():  # the pool is at work
            assert proc.poll() is None and time.monotonic() < end
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)  # what a terminal sends on Ctrl-C: every process
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("interrupted:")
    done = len((out / "trials.jsonl").read_text().splitlines())
    assert done < 100  # it stopped then, it did not finish the running trials first


def test_a_picture_cut_short_leaves_the_one_before(tmp_path):
    from sim.render import pyplot, save_figure

    out = tmp_path / "paths.png"
    fig = pyplot().figure()
    save_figure(fig, out)
    before = out.read_bytes()
    fig = pyplot().figure()

    def dies_half_way(target, **kwargs):  # as an interrupted savefig would: bytes, then death
        if isinstance(target, (str, Path)):
            Path(target).write_bytes(before[:10])
        else:
            target.write(before[:10])
        raise KeyboardInterrupt

    fig.savefig = dies_half_way
    with pytest.raises(KeyboardInterrupt):
        save_figure(fig, out)
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paths.png"]
    pyplot().close(fig)
