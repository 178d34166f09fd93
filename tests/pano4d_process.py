"""Helpers for tests that run the real `pano4d` command in a subprocess.

`pano4d` runs on one torch and one lavapipe thread: a run is then reproducible bit for bit
(docs/design.md, "Conventions"), and the tests do not contend for the shared cores.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from pano4d.synth import run_synth

ONE_THREAD = {"OMP_NUM_THREADS": "1", "LP_NUM_THREADS": "1"}
# A few steps of each stage; a checkpoint inside every optimisation (pano4d train
# --checkpoint-every 4).
TINY = {"view_size": 32, "init_stride": 8, "align_iterations": 20, "gaussian_iterations": 12}


def tiny_scene(folder: Path, frames: int = 3, seed: int = 0) -> Path:
    """A 512×256 synthetic scene (the smallest panorama pano4d takes) that trains in seconds;
    returns its scene.yaml."""
    path = run_synth(folder, 512, 256, frames, seed, views=2)
    text = path.read_text().replace("speed: 20", "speed: 3")  # less for the flow tracer to trace
    knobs = ", ".join(f"{k}: {v}" for k, v in TINY.items())
    path.write_text(text + f"overrides: {{{knobs}}}\n")
    return path


def python(
    *args: str | Path, env: dict[str, str] | None = None, prefix: tuple[str, ...] = ()
) -> subprocess.CompletedProcess[str]:
    """``python ARGS`` in a subprocess on one thread (``prefix``: a command to run it under)."""
    command = [*prefix, sys.executable, *map(str, args)]
    full_env = {**os.environ, **ONE_THREAD, **(env or {})}
    return subprocess.run(command, env=full_env, capture_output=True, text=True, timeout=600)


def pano4d(
    *args: str | Path, env: dict[str, str] | None = None, prefix: tuple[str, ...] = ()
) -> subprocess.CompletedProcess[str]:
    """``pano4d ARGS`` in a subprocess on one thread."""
    return python("-m", "pano4d.cli", *args, env=env, prefix=prefix)


def error_line(result: subprocess.CompletedProcess[str], code: int = 2) -> str:
    """The one `error:` line of a failed command; checks the exit code and that no
    traceback was printed."""
    assert result.returncode == code, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, result.stderr
    return lines[0]


def tree_digest(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder``, by relative path."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


class TinyDisk:
    """A tmpfs in a mount namespace of its own, held open by a sleeping process: commands
    run inside the namespace (``pano4d(..., prefix=disk.enter)``), the test reads and writes
    the same files through ``disk.root``. Gone (with its files) when the holder ends."""

    def __init__(self, holder: subprocess.Popen[bytes], mountpoint: Path) -> None:
        self.holder = holder
        self.mountpoint = mountpoint  # the path inside the namespace
        self.root = Path(f"/proc/{holder.pid}/root") / mountpoint.relative_to("/")
        self.enter = ("nsenter", f"--target={holder.pid}", "--mount", "--")

    def fill(self) -> Path:
        """Take every free byte; returns the filler file (delete it to free the disk)."""
        filler = self.root / "filler"
        fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        try:
            for chunk in (1 << 20, 4096, 1):
                with contextlib.suppress(OSError):
                    while True:
                        os.write(fd, bytes(chunk))
        finally:
            os.close(fd)
        assert os.statvfs(self.root).f_bavail == 0
        return filler


@contextmanager
def tiny_disk(mountpoint: Path, size: str = "64m") -> Iterator[TinyDisk]:
    """A ``size`` tmpfs at ``mountpoint`` (see TinyDisk); skips where no tmpfs can be
    mounted (it needs root or unprivileged user namespaces)."""
    if shutil.which("unshare") is None or shutil.which("nsenter") is None:
        pytest.skip("a full disk needs unshare and nsenter (util-linux) to mount a tmpfs")
    mountpoint.mkdir(parents=True, exist_ok=True)
    mount = f'mount -t tmpfs -o size={size} pano4d-test "{mountpoint}"'
    script = f"{mount} && echo ok && exec sleep 3600"
    holder = subprocess.Popen(
        ["unshare", "--mount", "--propagation", "private", "sh", "-c", script],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert holder.stdout is not None
    if holder.stdout.readline() != b"ok\n":
        holder.kill()
        reason = holder.communicate()[1].decode().strip()
        pytest.skip(f"cannot mount a tmpfs here for a full disk: {reason}")
    try:
        yield TinyDisk(holder, mountpoint)
    finally:
        holder.kill()
        holder.wait()
