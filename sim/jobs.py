"""Independent jobs (data shards, closed-loop trials, collection pushes) on a local process
pool or a Ray cluster.

Every pool in the project runs a module-level function on argument tuples and gathers the
results; :func:`run_jobs` is the one place that does it. Both backends call the very same
function with the very same arguments, each job in a worker with ``threads`` torch threads
(one by default), so the results, and the bytes written from them, do not depend on the
backend or on the number of workers.

Ray is an optional extra (``pip install -e ".[scale]"``), imported only when asked for. On a
cluster (``address``), the workers must see the same files as the driver (a shared
filesystem): the scenario, the model checkpoints and the output folders.
"""

from __future__ import annotations

import ctypes
import importlib.util
import multiprocessing
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from scenarios import InputError

BACKENDS = ("local", "ray")
SCALE_EXTRA = 'pip install -e ".[scale]"'
"""how to install the optional scaling dependencies (Ray, Gymnasium)"""


@dataclass(frozen=True)
class Backend:
    """Where independent jobs run."""

    kind: str = "local"
    """``local`` (forked processes on this machine) or ``ray``"""
    workers: int = 1
    """local: processes (1: in this process); ray: CPUs of a Ray instance started here"""
    address: str | None = None
    """ray: the address of an existing cluster (``ray start --head`` prints it; ``auto``
    finds one started on this machine); None starts a private instance of ``workers`` CPUs"""
    threads: int | None = None
    """torch threads per job (None: leave torch alone, for jobs that do not use it)"""

    def __post_init__(self) -> None:
        if self.kind not in BACKENDS:
            raise InputError(f"--backend must be one of {', '.join(BACKENDS)}, got {self.kind!r}")
        if self.workers < 1:
            raise InputError(f"--workers must be at least 1, got {self.workers}")
        if self.address is not None and self.kind != "ray":
            raise InputError("--address names a Ray cluster; it needs --backend ray")
        if self.threads is not None and self.threads < 1:
            raise InputError(f"--threads must be at least 1, got {self.threads}")
        if self.kind == "ray" and importlib.util.find_spec("ray") is None:
            raise InputError(f"--backend ray needs Ray: {SCALE_EXTRA}")
        if self.address is not None:
            check_reachable(self.address)


def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Refuse a Ray address of the form ``[ray://]HOST:PORT`` where nothing answers (Ray
    itself would retry for minutes); ``auto`` and ``local`` are Ray's to resolve."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as err:
        raise InputError(
            f"--address {address}: no Ray cluster answers there ({err.strerror or err}); "
            "give the address `ray start --head` printed, or auto"
        ) from None


@contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the body with ``n`` torch threads in this process, then restore the setting (None:
    leave it as it is)."""
    if n is None:
        yield
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


PR_SET_PDEATHSIG = 1
"""prctl(2) option: the signal a process gets when its parent dies (Linux)"""


def die_with_parent(parent_pid: int) -> None:
    """End this process when ``parent_pid`` (the process that started it) dies, however it
    dies, SIGKILL included: on Linux the kernel sends SIGKILL (``PR_SET_PDEATHSIG``); elsewhere a
    daemon thread polls the parent twice a second. Ctrl-C is left to the parent, which ends the
    workers itself, so that one interrupt gives one message, not one traceback a worker."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    else:

        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, daemon=True, name="watch-parent").start()
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)


def _init_worker(threads: int | None, parent_pid: int | None = None) -> None:
    if parent_pid is not None:
        die_with_parent(parent_pid)
    if threads is not None:
        import torch

        torch.set_num_threads(threads)


def _ray_job(fn: Callable[..., Any], args: tuple, threads: int | None, cwd: str) -> Any:
    """A job in a Ray worker: in the driver's folder where this node has it (relative paths
    then mean the same files), with ``threads`` torch threads."""
    if os.path.isdir(cwd):
        os.chdir(cwd)
    _init_worker(threads)
    return fn(*args)


def ray_module() -> Any:
    """The ``ray`` module, or a one-line InputError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise InputError(f"--backend ray needs Ray: {SCALE_EXTRA}") from None
    return ray


def _ray_results(
    fn: Callable[..., Any], jobs: Sequence[tuple], backend: Backend, ordered: bool
) -> Iterator[Any]:
    ray = ray_module()
    started_here = not ray.is_initialized()
    if started_here:
        if backend.address is None:
            ray.init(num_cpus=backend.workers, include_dashboard=False, log_to_driver=False)
        else:
            try:
                ray.init(address=backend.address, log_to_driver=False)
            except ConnectionError as err:
                raise InputError(
                    f"--address {backend.address}: no Ray cluster there ({err})"
                ) from None
    pending: list[Any] = []
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(_ray_job)
        cwd = os.getcwd()
        pending = [remote.remote(fn, args, backend.threads, cwd) for args in jobs]
        if ordered:
            while pending:
                yield ray.get(pending[0])
                pending.pop(0)
            return
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
    finally:
        if started_here:
            ray.shutdown()
        else:  # a cluster of someone else's: the jobs nobody will read must not run on
            for ref in pending:
                ray.cancel(ref)


def run_jobs(
    fn: Callable[..., Any], jobs: Sequence[tuple], backend: Backend, *, ordered: bool = False
) -> Iterator[Any]:
    """``fn(*args)`` for every ``args`` in ``jobs`` on ``backend``; yields the results as they
    complete (``ordered``: in the order of ``jobs``).

    ``fn`` must be a module-level function (the workers import it by name), and whatever it
    returns must pickle. A job's exception is raised here.
    """
    if backend.kind == "ray":
        yield from _ray_results(fn, jobs, backend, ordered)
    elif backend.workers == 1:
        with torch_threads(backend.threads):
            for args in jobs:
                yield fn(*args)
    else:
        ctx = multiprocessing.get_context("fork")
        pool = ProcessPoolExecutor(
            max_workers=backend.workers, mp_context=ctx, initializer=_init_worker,
            initargs=(backend.threads, os.getpid()),
        )  # fmt: skip
        finished = False
        try:
            futures = [pool.submit(fn, *args) for args in jobs]
            for fut in futures if ordered else as_completed(futures):
                yield fut.result()
            finished = True
        finally:
            # after an error, Ctrl-C or a consumer that stopped reading, nobody reads the jobs
            # still running: the workers end now, so the command stops now, not after them
            if not finished:
                for proc in list(pool._processes.values()):
                    proc.kill()
            pool.shutdown(wait=True, cancel_futures=True)
