"""``pano4d regions show | save | preview``: the region editor's file side as commands.

``pano4d-view --edit scene.yaml`` runs them (``python -m pano4d.cli regions …``); they
also script: regions go in as JSON on stdin (``{"regions": [...]}``, see
:mod:`pano4d.region_edit`) and every command prints one JSON object on stdout.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from pano4d.errors import fail

app = typer.Typer(
    name="regions",
    help="Read, save and preview a scene's regions (what pano4d-view --edit runs).",
    no_args_is_help=True,
)


def _regions_from_stdin() -> list[dict[str, Any]]:
    try:
        payload = json.loads(sys.stdin.read())
    except json.JSONDecodeError as error:
        fail(f"stdin: expected JSON {{\"regions\": [...]}}, got malformed JSON ({error})")
    regions = payload.get("regions") if isinstance(payload, dict) else None
    if not isinstance(regions, list) or not all(isinstance(r, dict) for r in regions):
        fail('stdin: expected {"regions": [ {...}, ... ]}: a list of region mappings')
    return regions


def _run(action: Any) -> None:
    """Print ``action()``'s result as JSON, or fail with its ConfigError / ImageError."""
    from pano4d.config import ConfigError
    from pano4d.images import ImageError

    try:
        result = action()
    except (ConfigError, ImageError) as error:
        fail(str(error))
    print(json.dumps(result))


@app.command()
def show(
    scene: Annotated[Path, typer.Argument(help="The scene.yaml.")],
    work: Annotated[Path, typer.Option(help="Folder for the display panorama and masks.")],
) -> None:
    """The panorama and regions of SCENE as the editor shows them (JSON on stdout)."""
    from pano4d.region_edit import open_for_editing

    _run(lambda: open_for_editing(scene, work))


@app.command()
def save(scene: Annotated[Path, typer.Argument(help="The scene.yaml to update.")]) -> None:
    """Replace SCENE's regions by those on stdin; comments and the other keys stay."""
    from pano4d.region_edit import save_regions

    regions = _regions_from_stdin()
    _run(lambda: save_regions(scene, regions))


@app.command()
def preview(
    scene: Annotated[Path, typer.Argument(help="The scene.yaml (settings and panorama).")],
    out: Annotated[Path, typer.Option(help="Folder for the preview frames (PNG).")],
    width: Annotated[int, typer.Option(help="Width of the downscaled panorama.")] = 512,
) -> None:
    """Animate the regions on stdin with the flow backend, on a small panorama."""
    from pano4d.region_edit import render_preview

    regions = _regions_from_stdin()
    _run(lambda: render_preview(scene, regions, out, width))
