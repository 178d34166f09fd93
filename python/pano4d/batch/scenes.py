"""Which scenes a batch runs: the scene.yaml files its arguments name (``collect_scenes``)
and the short name each shows in the table (``scene_name``)."""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from pathlib import Path

from pano4d.errors import InputError

SCENE_SUFFIXES = (".yaml", ".yml")


class BatchError(InputError, ValueError):
    """Bad input for the whole batch (missing scene files, impossible resources, no Ray)."""


def collect_scenes(arguments: Sequence[Path]) -> list[Path]:
    """The scene.yaml files the arguments name, in order, each once.

    An argument is a scene file (``.yaml`` / ``.yml``), a folder (every scene file below
    it, sorted; hidden folders left out), or a list file: one scene file or folder a line,
    relative to the list's folder, with blank lines and ``#`` comments ignored.
    """
    found: list[Path] = []

    def add(path: Path, where: str, in_list: bool) -> None:
        if not path.exists():
            raise BatchError(f"{where}: {path} not found")
        if path.is_dir():
            inside = sorted(
                p
                for p in path.rglob("*")
                if p.suffix in SCENE_SUFFIXES
                and p.is_file()
                and not any(part.startswith(".") for part in p.relative_to(path).parts)
            )
            if not inside:
                raise BatchError(f"{where}: {path} holds no .yaml scene files")
            found.extend(p.resolve() for p in inside)
        elif path.suffix in SCENE_SUFFIXES:
            found.append(path.resolve())
        elif in_list:
            raise BatchError(f"{where}: {path} is neither a scene .yaml nor a folder")
        else:
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                entry = line.split("#", 1)[0].strip()
                if entry:
                    add(path.parent / entry, f"{path} line {number}", in_list=True)

    for argument in arguments:
        add(Path(argument), "scene argument", in_list=False)
    if not found:
        raise BatchError("no scenes given")
    return list(dict.fromkeys(found))


def scene_name(path: Path, root: Path) -> str:
    """A short name for a scene: its path relative to ``root`` when below it, and only the
    folder for a file called scene.yaml (what ``pano4d synth`` writes)."""
    shown = path.parent if path.name == "scene.yaml" else path
    with contextlib.suppress(ValueError):
        return str(shown.relative_to(root)) if shown != root else path.name
    return str(shown)
