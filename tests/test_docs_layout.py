"""docs/design.md's module list and README's layout name every module of python/pano4d,
and nothing that is not there: a module added, moved or renamed without its line fails here
with the module's name.

design.md: the block after "The Python package, one line a module:", a path relative to
python/pano4d first on each line. README: the ``python/pano4d/`` part of the "## Layout"
block, file names (``name.py``) on the lines of the package folder; a line starting with a
subpackage (``  lift/``) and the lines indented under it name that subpackage's modules. A
package's ``__init__.py`` may be left out (its package's line speaks for it).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "python" / "pano4d"
DESIGN = ROOT / "docs" / "design.md"
README = ROOT / "README.md"
DESIGN_HEADING = "The Python package, one line a module:"


def modules() -> set[str]:
    """Every Python module of the package, as a path relative to python/pano4d."""
    return {
        path.relative_to(PACKAGE).as_posix()
        for path in PACKAGE.rglob("*.py")
        if "__pycache__" not in path.parts
    }


def code_block_after(text: str, marker: str, source: Path) -> str:
    """The first ``` block after ``marker`` in ``text``."""
    if marker not in text:
        raise AssertionError(f"{source.name}: no {marker!r} found")
    parts = text.split(marker, 1)[1].split("```")
    if len(parts) < 3:
        raise AssertionError(f"{source.name}: no code block after {marker!r}")
    return parts[1]


def design_listing() -> list[str]:
    block = code_block_after(DESIGN.read_text(encoding="utf-8"), DESIGN_HEADING, DESIGN)
    return [line.split()[0] for line in block.splitlines() if line.strip()]


def readme_listing() -> list[str]:
    block = code_block_after(README.read_text(encoding="utf-8"), "## Layout", README)
    lines = block.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith("python/pano4d/")), None)
    if start is None:
        raise AssertionError("README.md: the Layout block has no python/pano4d/ line")
    listed: list[str] = []
    package = ""
    for line in lines[start + 1 :]:
        if line and not line.startswith(" "):
            break  # the next top-level folder
        subpackage = re.match(r"  (\w+)/", line)
        if subpackage:
            package = subpackage[1] + "/"
        elif re.match(r"  \S", line):
            package = ""  # a line of the package folder's own modules
        listed += [package + name for name in re.findall(r"\b\w+\.py\b", line)]
    return listed


@pytest.mark.parametrize(
    ("doc", "listing"),
    [("docs/design.md's module list", design_listing), ("README's layout", readme_listing)],
    ids=["design", "readme"],
)
def test_the_docs_list_every_module_and_only_those(
    doc: str, listing: Callable[[], list[str]]
) -> None:
    listed = listing()
    assert listed, f"{doc} lists no module"
    gone = [name for name in listed if not (PACKAGE / name).is_file()]
    assert not gone, f"{doc} names {', '.join(gone)}, not in python/pano4d: fix or drop the line"
    missing = sorted(name for name in modules() - set(listed) if Path(name).name != "__init__.py")
    assert not missing, f"{doc} leaves out {', '.join(missing)}: add a line for each"
