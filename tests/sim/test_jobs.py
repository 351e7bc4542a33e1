"""The job backends: the local pool and Ray run the same function to the same results."""

import importlib.util
import os

import pytest

from scenarios import InputError
from se3push.cli import main
from sim.dataset import generate
from sim.jobs import Backend, run_jobs
from tests.sim.test_dataset import CFG, shard_bytes


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def test_the_local_pool_gives_every_result_in_order_when_asked():
    jobs = [(x,) for x in range(6)]
    for backend in (Backend(), Backend("local", 2)):
        got = list(run_jobs(_square_and_pid, jobs, backend, ordered=True))
        assert [r for r, _ in got] == [x * x for x in range(6)]
    assert {p for _, p in run_jobs(_square_and_pid, jobs, Backend())} == {os.getpid()}


def _mark_or_fail(x: int, folder: str) -> int:
    import time

    if x == 1:
        raise ValueError("job 1 failed")
    open(os.path.join(folder, str(x)), "w").close()
    time.sleep(0.2)
    return x


def test_a_failing_job_stops_the_pool_without_running_the_rest(tmp_path):
    jobs = [(x, str(tmp_path)) for x in range(16)]
    with pytest.raises(ValueError, match="job 1 failed"):
        list(run_jobs(_mark_or_fail, jobs, Backend("local", 2), ordered=True))
    ran = len(list(tmp_path.iterdir()))
    assert 1 <= ran <= 6  # those already handed to the workers; not all 15


def test_bad_backends_are_refused_with_what_to_do(monkeypatch, capsys):
    with pytest.raises(InputError, match="--backend must be one of local, ray"):
        Backend("dask")
    with pytest.raises(InputError, match="--address .* needs --backend ray"):
        Backend(address="auto")
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a)
    )
    assert main(["data", "--scenario", "tiny", "--episodes", "1", "--backend", "ray",
                 "--out", "unused"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert err == 'error: --backend ray needs Ray: pip install -e ".[scale]"'
    assert not os.path.exists("unused")


@pytest.mark.scale
def test_an_address_where_no_cluster_answers_is_refused_at_once(capsys):
    pytest.importorskip("ray", reason='the scale extra: pip install -e ".[scale]"')
    with pytest.raises(InputError, match="--address 127.0.0.1:1: no Ray cluster answers there"):
        Backend("ray", address="127.0.0.1:1")  # not after minutes of Ray's retries


@pytest.mark.scale
def test_ray_runs_the_jobs_in_its_own_workers(ray_local):
    jobs = [(x,) for x in range(6)]
    got = list(run_jobs(_square_and_pid, jobs, Backend("ray", 2), ordered=True))
    assert [r for r, _ in got] == [x * x for x in range(6)]
    assert os.getpid() not in {p for _, p in got}
    unordered = list(run_jobs(_square_and_pid, jobs, Backend("ray", 2)))
    assert sorted(r for r, _ in unordered) == [x * x for x in range(6)]


@pytest.mark.scale
def test_ray_writes_the_same_shards_as_the_local_pool_and_resumes(ray_local, tmp_path):
    local = tmp_path / "local"
    generate(CFG, local, workers=2, progress=False)
    generate(CFG, tmp_path / "ray2", workers=2, backend="ray", progress=False)
    assert shard_bytes(tmp_path / "ray2") == shard_bytes(local)
    # resume: a folder with one shard lost is finished by Ray to the same bytes
    (tmp_path / "ray2" / "shard_00001.npz").unlink()
    generate(CFG, tmp_path / "ray2", workers=2, backend="ray", progress=False)
    assert shard_bytes(tmp_path / "ray2") == shard_bytes(local)
