"""Shard files: deterministic, compressed, atomically written bundles of numpy arrays.

A shard is a ZIP of ``.npy`` members (what ``np.load`` reads) written with fixed timestamps,
so that the same arrays always give the same bytes, and written to a temporary name and
renamed into place, so that a reader never sees half a shard.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from scenarios import InputError
from sim.folders import temporary_path, unwritable

FIXED_TIME = (1980, 1, 1, 0, 0, 0)


class DataError(InputError):
    """A dataset folder or file is missing, mismatched, truncated or corrupted."""


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder, fsync, rename."""
    path = Path(path)
    tmp = temporary_path(path)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as err:  # a full disk, say: no partial file is left, under any name
        tmp.unlink(missing_ok=True)
        if isinstance(err, OSError) and (refused := unwritable(err, path.parent)) is not None:
            raise refused from err
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def append_text(path: Path, text: str) -> None:
    """Append ``text`` to ``path`` (a log whose reader skips a line cut short)."""
    try:
        with open(path, "a") as f:
            f.write(text)
    except OSError as err:
        raise (unwritable(err, Path(path).parent) or err) from err


def atomic_write_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(Path(path), (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode())


def portable_path(path: str | Path) -> str:
    """``path`` as results should record it: relative to the current directory when it lies
    under it (so no machine's folders end up in committed results), else as given."""
    p = Path(path)
    if not p.is_absolute():
        return str(p)
    cwd = Path.cwd()
    for base, q in ((cwd, Path(os.path.normpath(p))), (cwd.resolve(), p.resolve())):
        if q.is_relative_to(base):
            return str(q.relative_to(base))
    return str(path)


def encode_arrays(arrays: dict[str, np.ndarray]) -> bytes:
    """The bytes of a compressed ``.npz`` holding ``arrays``, identical for identical input."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
        for name in sorted(arrays):
            member = io.BytesIO()
            np.lib.format.write_array(
                member, np.ascontiguousarray(arrays[name]), allow_pickle=False
            )
            info = zipfile.ZipInfo(f"{name}.npy", date_time=FIXED_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue())
    return buf.getvalue()


def write_shard(path: Path, arrays: dict[str, np.ndarray]) -> str:
    """Write a shard atomically; returns its sha256."""
    data = encode_arrays(arrays)
    atomic_write_bytes(Path(path), data)
    return hashlib.sha256(data).hexdigest()


def read_shard(path: Path, *, expected_sha256: str | None = None) -> dict[str, np.ndarray]:
    """Read every array of a shard.

    Raises:
        DataError: the file is missing, truncated, corrupted or fails its checksum; the
            message names the file and what to do.
    """
    path = Path(path)
    fix = "delete it and run the same `se3push data` command again to regenerate it"
    if not path.is_file():
        raise DataError(f"shard {path} is missing; {fix}")
    if expected_sha256 is not None and sha256(path) != expected_sha256:
        raise DataError(f"shard {path} fails its checksum (truncated or corrupted); {fix}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}
    except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError) as err:
        raise DataError(f"shard {path} cannot be read ({err}); {fix}") from None
