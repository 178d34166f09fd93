"""The Python-side readers on damaged real files: truncation and byte flips.

``pano4d.ply4d.read`` (.ply4d, versions 1 and 2) and ``pano4d.ply4d.read_ply`` (.ply and
SuperSplat .compressed.ply) read damaged copies of the real files in ../shared/data (read
from there, written only to a temporary folder). Every case either reads the original count (for a
.ply4d, whose checksums cover its data, the original scene exactly) or raises the one
documented error, ValueError, with one line that names the file: never another exception,
a Rust panic, or a silently wrong count.

Cases per test: ``PANO4D_FUZZ_EXAMPLES`` (default 40, a few seconds each in CI); a longer run:
``PANO4D_FUZZ_EXAMPLES=2000 pytest tests/test_fuzz_readers.py --hypothesis-show-statistics``.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pano4d import ply4d
from pano4d.gaussians import Gaussians
from pano4d.spacetime import SpacetimeGaussians, TimeModel

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
EXAMPLES = int(os.environ.get("PANO4D_FUZZ_EXAMPLES", "40"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


@dataclass
class Seed:
    """An undamaged file, where its header ends, and how to read and check a damaged copy."""

    data: bytes
    header_len: int  # bytes before the records (.ply) or the first section (.ply4d)
    counts: list[int]  # positions of the bytes that say how many records there are
    suffix: str
    read_and_check: Callable[[Path], None]  # raises ValueError, or AssertionError if wrong


def _same_bits(a: Gaussians, b: Gaussians) -> bool:
    x, y = a.to_numpy(), b.to_numpy()
    return x.keys() == y.keys() and all(
        x[k].shape == y[k].shape and np.array_equal(x[k].view(np.uint32), y[k].view(np.uint32))
        for k in x
    )


def _ply_seed(path: Path) -> Seed:
    data = path.read_bytes()
    count = len(ply4d.read_ply(path))

    def check(damaged: Path) -> None:
        assert len(ply4d.read_ply(damaged)) == count, "read with a wrong count"

    header_len = data.index(b"end_header\n") + len(b"end_header\n")
    counts, start = [], 0
    for line in data[:header_len].split(b"\n"):
        if line.startswith(b"element "):  # its digits: "element vertex 1000"
            counts += [start + i for i, c in enumerate(line) if 48 <= c <= 57]
        start += len(line) + 1
    return Seed(data, header_len, counts, "".join(path.suffixes), check)


def _ply4d_seed(folder: Path, spacetime: bool) -> Seed:
    """A .ply4d made from the real 3DGS file: 600 static Gaussians, and three dynamic sets
    (version 1) or 400 spacetime Gaussians looping over three frames (version 2)."""
    train = ply4d.read_ply(DATA / "gs_train1000.ply")
    times = [0.0, 0.125, 0.25]
    if spacetime:
        gen = np.random.default_rng(0)
        model = TimeModel(period=3, colour_harmonics=1, position_harmonics=1)

        def values(*shape: int) -> torch.Tensor:
            return torch.from_numpy(gen.standard_normal(shape, dtype=np.float32))

        dynamic: list[Gaussians] | SpacetimeGaussians = SpacetimeGaussians(
            model, train[600:], values(400), values(400), values(400, 2, 3), values(400, 2, 3)
        )
    else:
        dynamic = [train[600:700], train[700:850], train[850:]]
    scene = ply4d.Scene4D(train[:600], dynamic, times, 8.0)
    path = folder / f"seed-{int(spacetime)}.ply4d"
    ply4d.write(path, scene)
    data = path.read_bytes()
    json_len, sections = struct.unpack_from("<II", data, 12)

    def check(damaged: Path) -> None:
        back = ply4d.read(damaged)
        assert _same_bits(back.static, scene.static), "the static set read, but not as written"
        assert back.num_times == scene.num_times, "a wrong number of timestamps"
        if isinstance(scene.dynamic, SpacetimeGaussians):
            assert isinstance(back.dynamic, SpacetimeGaussians), "not a spacetime set"
            assert back.dynamic.model == scene.dynamic.model, "another time model"
            assert _same_bits(back.dynamic.canonical, scene.dynamic.canonical), "canonical"
            for name in ("time_centre", "time_log_width", "colour_terms", "position_terms"):
                got, want = getattr(back.dynamic, name), getattr(scene.dynamic, name)
                assert torch.equal(got, want), f"{name} read, but not as written"
        for t in range(scene.num_times):
            assert _same_bits(back.dynamic_at(t), scene.dynamic_at(t)), f"timestamp {t}"
        assert back.timestamps == scene.timestamps

    table = 32 + json_len
    # The preamble's header length and section count, each entry's offset, length, count.
    counts = [*range(12, 20)]
    for entry in range(sections):
        counts += range(table + 40 * entry + 8, table + 40 * entry + 32)
    return Seed(data, table + 40 * sections, counts, ".ply4d", check)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def seeds(folder: Path) -> dict[str, Seed]:
    return {
        "ply": _ply_seed(DATA / "gs_train1000.ply"),
        "compressed": _ply_seed(DATA / "gs_guitar.compressed.ply"),
        "ply4d": _ply4d_seed(folder, spacetime=False),
        "ply4d-v2": _ply4d_seed(folder, spacetime=True),
    }


@st.composite
def damage(draw: st.DrawFn, seed: Seed) -> tuple[list[tuple[int, int]], int]:
    """Bytes overwritten (position, value) and a length to cut the file to (its size: no
    cut), at least one of both. A third of the positions are the bytes that give a count
    and a third anywhere in the header, where a reader's trust lies; values are often
    digits, so that a count in a .ply's text can turn into another count."""
    size, header = len(seed.data), seed.header_len
    position = st.one_of(
        st.sampled_from(seed.counts), st.integers(0, header - 1), st.integers(0, size - 1)
    )
    value = st.one_of(st.integers(0, 255), st.sampled_from(b"0123456789"))
    edits = draw(st.lists(st.tuples(position, value), max_size=6))
    cut = draw(st.one_of(st.just(size), st.integers(0, size - 1)))
    if not edits and cut == size:
        cut = draw(st.integers(0, size - 1))
    return edits, cut


def _check_damaged(seed: Seed, folder: Path, edits: list[tuple[int, int]], cut: int) -> str:
    """Read a damaged copy; returns "read" or "refused", or fails the test."""
    data = bytearray(seed.data)
    for at, value in edits:
        data[at] = value
    path = folder / f"damaged{seed.suffix}"
    path.write_bytes(bytes(data[:cut]))
    try:
        seed.read_and_check(path)
    except ValueError as error:
        message = str(error)
        assert str(path) in message and "\n" not in message, message
        return "refused"
    except BaseException as error:  # a Rust panic arrives as pyo3's PanicException
        if isinstance(error, AssertionError | KeyboardInterrupt):
            raise
        pytest.fail(f"{type(error).__name__} instead of ValueError: {error}")
    # It read, and read right; a truncated file never may.
    assert cut == len(seed.data), f"read a file cut to {cut} of {len(seed.data)} bytes"
    return "read"


@pytest.mark.parametrize("kind", ["ply", "compressed", "ply4d", "ply4d-v2"])
def test_damaged_files_read_right_or_fail_with_one_line_naming_the_file(
    kind: str, seeds: dict[str, Seed], folder: Path
) -> None:
    seed = seeds[kind]
    outcomes: list[str] = []

    @FUZZ
    @given(damage(seed))
    def run(case: tuple[list[tuple[int, int]], int]) -> None:
        outcomes.append(_check_damaged(seed, folder, *case))

    run()
    print(f"{kind}: {len(outcomes)} damaged files, {outcomes.count('read')} read right, "
          f"{outcomes.count('refused')} refused with one line")  # fmt: skip
    assert len(outcomes) >= EXAMPLES and "refused" in outcomes


@pytest.mark.parametrize("kind", ["ply", "compressed", "ply4d", "ply4d-v2"])
def test_damage_to_the_records_alone_reads_in_a_ply_and_is_refused_in_a_ply4d(
    kind: str, seeds: dict[str, Seed], folder: Path
) -> None:
    """Overwritten bytes after the header only. A .ply has no checksum, so they are values,
    not damage its reader can see: it must read them with the original count rather than
    refuse. A .ply4d's sections are checksummed: it must refuse them, naming the file (or
    read the original, where only padding was hit)."""
    seed = seeds[kind]
    outcomes: list[str] = []
    position = st.integers(seed.header_len, len(seed.data) - 1)

    @FUZZ
    @given(st.lists(st.tuples(position, st.integers(0, 255)), min_size=1, max_size=6))
    def run(edits: list[tuple[int, int]]) -> None:
        outcomes.append(_check_damaged(seed, folder, edits, len(seed.data)))

    run()
    print(f"{kind}: {len(outcomes)} files with damaged records, {outcomes.count('read')} read")
    assert len(outcomes) >= EXAMPLES
    if kind.startswith("ply4d"):
        assert "refused" in outcomes
    else:
        assert set(outcomes) == {"read"}
