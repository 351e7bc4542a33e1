"""Output folders: one writer at a time, and a clear word when a folder cannot be written.

Every command that writes a folder (data, train, trials, improve, study, eval) holds an
exclusive lock on it while it runs (:func:`writes_folder`), so a second command on the same
folder is refused at once, naming the process that holds it, instead of both writing it. The
lock is ``flock(2)`` on a file in the folder: the kernel releases it when its holder dies, so a
lock left by a killed process never blocks the next run, and the temporary files a killed writer
left unfinished are removed when the folder is next taken.
"""

from __future__ import annotations

import errno
import fcntl
import functools
import inspect
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from scenarios import InputError

LOCK_NAME = ".se3push.lock"
"""the lock file in a folder being written (its content: the holder's pid and command)"""

TEMPORARY = ".*.tmp-*"
"""the name pattern of a file being written atomically (:func:`temporary_path`): one found
when a folder is taken was left by a killed writer, and is removed"""


def temporary_path(path: Path) -> Path:
    """Where ``path`` is written before it is renamed into place (it matches ``TEMPORARY``)."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


DISK_ERRORS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
}
"""the errors that mean a folder cannot be written (not a bug of ours), with their plain words"""

_held: dict[Path, int] = {}
"""folders this process holds, with how many nested holders: a command that writes a folder
and calls another that writes the same one (a study's trials, say) does not lock itself out"""

F = TypeVar("F", bound=Callable[..., Any])


def unwritable(err: OSError, folder: str | Path | None = None) -> InputError | None:
    """The one-line error for ``err`` if it means a folder cannot be written (full, read-only,
    no permission), else None. ``folder``: the folder to name (default: the file's folder)."""
    words = DISK_ERRORS.get(err.errno)
    if words is None:
        return None
    if folder is None:
        if not err.filename:
            return InputError(f"cannot write the output: {words}; free some space, or choose a "
                              "folder you can write")  # fmt: skip
        name = Path(os.fsdecode(err.filename))
        folder = name if name.is_dir() else name.parent
    return InputError(
        f"cannot write to {folder}: {words}; free some space, or choose a folder you can write"
    )


def _holder(lock: Path) -> str:
    """Who holds ``lock``, from what it wrote into it: pid and command line."""
    try:
        pid, _, command = lock.read_text().partition("\n")
    except OSError:
        return "another process"
    return f"process {pid.strip()} ({command.strip()})" if pid.strip() else "another process"


def _command_line() -> str:
    try:
        raw = Path(f"/proc/{os.getpid()}/cmdline").read_bytes()
        return " ".join(a.decode(errors="replace") for a in raw.split(b"\0") if a)
    except OSError:
        import sys

        return " ".join(sys.argv)


@contextmanager
def exclusive(folder: str | Path) -> Iterator[Path]:
    """Hold ``folder`` (created if needed) for writing: refuse it, with an InputError naming the
    holder, while another process holds it; refuse a folder that cannot be written, naming it.
    """
    folder = Path(folder)
    created = not folder.exists()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        key = folder.resolve()
        fd = None if key in _held else os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:  # under a file, read-only, forbidden, full: not a folder to write
        raise PermissionError(
            f"cannot write to {folder} ({err.strerror}); choose another output folder"
        ) from None
    if fd is None:  # held by this process already
        _held[key] += 1
        try:
            yield folder
        finally:
            _held[key] -= 1
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(
                f"{folder} is being written by {_holder(folder / LOCK_NAME)}; wait for it to "
                "end, or choose another output folder"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n{_command_line()}\n".encode(), 0)
        for tmp in folder.glob(TEMPORARY):  # a killed writer's unfinished file: never read
            tmp.unlink(missing_ok=True)
        _held[key] = 1
        try:
            yield folder
        finally:
            del _held[key]
            if created and [p.name for p in folder.iterdir()] == [LOCK_NAME]:
                (folder / LOCK_NAME).unlink()  # refused before writing: no folder left behind
                folder.rmdir()
    finally:
        os.close(fd)  # releases the lock (the kernel does the same for a killed process)


def writes_folder(folder_of: Callable[[inspect.BoundArguments], str | Path]) -> Callable[[F], F]:
    """Decorate a function that writes a folder: it runs holding :func:`exclusive` on the
    folder ``folder_of`` picks out of its bound arguments."""

    def decorate(fn: F) -> F:
        signature = inspect.signature(fn)

        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            with exclusive(folder_of(bound)):
                return fn(*args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return decorate
