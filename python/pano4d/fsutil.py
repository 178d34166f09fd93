"""Atomic file output: write to a temporary file beside the target, then rename.

A reader never sees a half-written file, and a failed write (full disk, a kill) leaves
whatever was at the target before untouched. A write that fails on a full disk raises
``OSError(ENOSPC)`` naming the target, whatever the writer (torch, OpenImageIO, ffmpeg)
made of the failure.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path with the target's suffix; rename it over ``target`` on success."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except Exception as error:
        # Writers report a full disk in their own words (torch: "unexpected pos", OpenEXR:
        # "Failed to write pixel data"); say what happened, while the temporary file still
        # holds the space it took.
        if _disk_full(error, tmp.parent):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target)) from error
        raise
    finally:
        tmp.unlink(missing_ok=True)


# Less free space than this after a failed write: the write failed because the disk is full
# (a writer fails on the buffer it could not write, so a little space may be left).
FULL_DISK_BYTES = 1 << 20


def _disk_full(error: Exception, folder: Path) -> bool:
    if isinstance(error, OSError) and error.errno == errno.ENOSPC:
        return True
    try:
        stats = os.statvfs(folder)
    except OSError:
        return False
    return stats.f_bavail * stats.f_frsize < FULL_DISK_BYTES


def write_text_atomic(target: str | os.PathLike[str], text: str) -> None:
    with atomic_path(target) as tmp:
        tmp.write_text(text)


def write_json_atomic(target: str | os.PathLike[str], data: Any) -> None:
    write_text_atomic(target, json.dumps(data, indent=2) + "\n")
