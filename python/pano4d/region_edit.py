"""The file side of the region editor (``pano4d-view --edit scene.yaml``).

The viewer draws; this module reads and writes, so that scene.yaml has one owner
(:mod:`pano4d.config`) and what the viewer saves is what ``pano4d check`` accepts:

* :func:`open_for_editing`: the panorama as an 8-bit PNG for display, every mask region
  as a PNG at the editing resolution, and the regions as scene.yaml has them.
* :func:`save_regions`: the edited regions back into scene.yaml. Only the items of the
  ``regions`` list that changed are rewritten: a region the editor left as it was keeps
  its text and comments byte for byte, a changed one keeps the comment lines above it,
  and every byte outside the list, comments and key order included, stays as it was.
  Painted masks are written as PNG beside scene.yaml. The new file is validated with
  :func:`load_config` before it replaces the old one, atomically.
* :func:`render_preview`: the ``flow`` animator on a downscaled panorama for regions that
  need not be saved yet.

The viewer sends regions as scene.yaml writes them (``name``, one of ``box`` / ``click``
+ ``size`` / ``mask``, ``motion``), with ``mask_png`` in place of ``mask`` for a mask it
painted: a PNG (white = moves) at any size with the panorama's aspect.

Why a splice and not a round-trip YAML library (ruamel.yaml): PyYAML, which validation
already uses, gives every node's position in the text, so replacing the regions' span
keeps the rest of the file byte for byte, however it is formatted, and so does the span
of every region item that did not change; a round-trip loader re-emits the whole file
and normalises its indentation and spacing.
"""

from __future__ import annotations

import difflib
import json
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pano4d.config import ConfigError, PathLike, Region, SceneConfig, load_config, validate_config
from pano4d.fsutil import atomic_path
from pano4d.images import image_size, read_mask, read_panorama, write_image

# Painted masks are edited and saved at most this wide (the pipeline resizes a mask of the
# panorama's aspect): a stroke's undo copy stays small, and brushes are tens of pixels.
MASK_MAX_WIDTH = 2048
# The panorama is shown at most this wide.
DISPLAY_MAX_WIDTH = 4096
# The preview animates a panorama this wide (seconds on a CPU, see bench/RESULTS.md).
PREVIEW_WIDTH = 512

_REGION_KEYS = ("name", "box", "click", "size", "mask", "motion")


class EditError(ConfigError):
    """Edited regions that cannot be saved or previewed; the message says why."""


# --- opening -----------------------------------------------------------------------------
def mask_size(width: int, height: int) -> tuple[int, int]:
    """The editing resolution of masks for a width×height panorama."""
    scale = max(1, -(-width // MASK_MAX_WIDTH))
    while width % scale or height % scale:
        scale += 1
    return width // scale, height // scale


def open_for_editing(scene: PathLike, work_dir: PathLike) -> dict[str, Any]:
    """What the editor needs to show ``scene``: writes ``panorama.png`` (8-bit, at most
    DISPLAY_MAX_WIDTH wide) and ``mask-<i>.png`` per mask region into ``work_dir``.

    A scene without regions yet (``regions: []``) opens; anything else invalid raises
    ConfigError, as ``pano4d check`` would.
    """
    scene = Path(scene).resolve()
    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    cfg = load_config(scene, require_regions=False)
    width, height = image_size(cfg.panorama)
    mask_width, mask_height = mask_size(width, height)
    panorama = read_panorama(cfg.panorama)
    display = work / "panorama.png"
    write_image(display, _downscale(panorama, DISPLAY_MAX_WIDTH))
    as_written = _raw_regions(scene)
    regions = []
    for index, region in enumerate(cfg.regions):
        item = region.model_dump(mode="json", exclude_none=True, include=set(_REGION_KEYS))
        if region.mask is not None:
            # Keep the path as the file has it (relative stays relative).
            item["mask"] = as_written[index]["mask"]
            png = work / f"mask-{index}.png"
            write_image(png, read_mask(region.mask, mask_width, mask_height).astype(np.float32))
            item["mask_png"] = str(png)
        regions.append(item)
    return {
        "scene": str(scene),
        "panorama": str(cfg.panorama),
        "width": width,
        "height": height,
        "mask_width": mask_width,
        "mask_height": mask_height,
        "display": str(display),
        "frames": cfg.animate.frames,
        "fps": cfg.animate.fps,
        "regions": regions,
    }


def _raw_regions(scene: Path) -> list[dict[str, Any]]:
    data = yaml.safe_load(scene.read_text(encoding="utf-8"))
    return list(data.get("regions") or [])


def _downscale(image: np.ndarray, max_width: int) -> np.ndarray:
    """Area-average ``image`` (H, W, C) by the smallest integer factor that fits."""
    height, width = image.shape[:2]
    factor = -(-width // max_width)
    if factor == 1:
        return image
    h, w = height // factor, width // factor
    cropped = image[: h * factor, : w * factor]
    return cropped.reshape(h, factor, w, factor, -1).mean(axis=(1, 3))


# --- saving ------------------------------------------------------------------------------
def save_regions(scene: PathLike, regions: list[dict[str, Any]]) -> dict[str, Any]:
    """Write ``regions`` (see the module doc) into ``scene`` and painted masks beside it.

    Nothing is written unless the new scene.yaml validates; then the masks are written
    first and scene.yaml last, each atomically. Returns the written paths.
    """
    scene = Path(scene).resolve()
    if not scene.is_file():
        raise EditError(f"{scene}: config file not found")
    text = scene.read_text(encoding="utf-8")
    painted = _painted_masks(scene, regions)
    # Validate with the painted masks where they are now, before anything is written.
    staged = [_item(r, painted[i][0] if i in painted else None) for i, r in enumerate(regions)]
    validate_config(
        yaml.safe_load(splice_regions(text, staged, scene.parent)),
        base_dir=scene.parent,
        source=scene,
    )
    for src, dest in painted.values():
        with atomic_path(dest) as tmp:
            shutil.copyfile(src, tmp)
    final = [_item(r, painted[i][1].name if i in painted else None) for i, r in enumerate(regions)]
    with atomic_path(scene) as tmp:
        tmp.write_text(splice_regions(text, final, scene.parent), encoding="utf-8")
        try:
            load_config(tmp)
        except ConfigError as error:
            raise EditError(str(error).replace(str(tmp), str(scene))) from None
    return {"scene": str(scene), "masks": [str(dest) for _, dest in painted.values()]}


def _painted_masks(scene: Path, regions: list[dict[str, Any]]) -> dict[int, tuple[Path, Path]]:
    """{region index: (the viewer's PNG, where it goes beside scene.yaml)}; refuses empty
    masks, which would move nothing."""
    painted: dict[int, tuple[Path, Path]] = {}
    used: set[str] = set()
    for index, region in enumerate(regions):
        if "mask_png" not in region:
            continue
        src = Path(region["mask_png"])
        label = region.get("name") or f"region {index + 1}"
        if not read_mask(src, *image_size(src)).any():
            raise EditError(f"regions[{index}] ({label}): the painted mask is empty")
        slug = re.sub(r"[^a-z0-9]+", "-", label.lower()).strip("-") or f"region-{index + 1}"
        if slug in used:
            slug = f"{slug}-{index + 1}"
        used.add(slug)
        painted[index] = (src, scene.with_name(f"{scene.stem}.{slug}.mask.png"))
    return painted


def _item(region: dict[str, Any], painted_mask: Path | str | None) -> dict[str, Any]:
    """The region as scene.yaml writes it, keys in a fixed order; a painted mask's
    ``mask_png`` becomes ``mask: painted_mask``."""
    unknown = set(region) - {*_REGION_KEYS, "mask_png"}
    if unknown:
        raise EditError(f"unknown region key(s) {sorted(unknown)}; expected {_REGION_KEYS}")
    merged = dict(region)
    if "mask_png" in region:
        merged["mask"] = str(painted_mask)
    for key in ("box", "click"):  # whole pixels read best as integers
        if isinstance(merged.get(key), list):
            merged[key] = [_whole(v) for v in merged[key]]
    return {key: merged[key] for key in _REGION_KEYS if merged.get(key) is not None}


def _whole(value: Any) -> Any:
    return int(value) if isinstance(value, float) and value.is_integer() else value


def splice_regions(text: str, regions: list[dict[str, Any]], base_dir: Path) -> str:
    """``text`` (a scene.yaml) with its ``regions`` list made ``regions``.

    Every byte outside the list's span is kept: comments before its first item and after
    its last, and the rest of the file. In a block list, a region that did not change (the
    same ``region_key``; relative mask paths against ``base_dir``) keeps its text byte for
    byte with its comments, a changed one keeps the comment lines just above it, and only
    the changed, added and removed regions' lines change (``_item_edits`` pairs them). A
    flow or empty list (``regions: []``) becomes a block list; a missing key is appended.
    """
    newline = "\r\n" if "\r\n" in text else "\n"
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    if root is not None and not isinstance(root, yaml.MappingNode):
        raise EditError("scene.yaml is not a mapping of keys")
    pairs = root.value if root is not None else []
    entry = next(((k, v) for k, v in pairs if k.value == "regions"), None)
    if entry is None:
        ending = "" if not text or text.endswith("\n") else newline
        return text + ending + "regions:" + newline + _block(regions, 2, newline)
    key, value = entry
    if value.start_mark.index < key.end_mark.index:
        raise EditError("regions is an alias of a list defined elsewhere; write it out in place")
    if isinstance(value, yaml.SequenceNode) and not value.flow_style and value.value:
        return _splice_items(text, key, value, regions, base_dir, newline)
    # A flow list or a scalar: a block list on the lines after the key. An empty value's
    # marks sit on the next token, so it is taken to end right after the colon.
    if value.start_mark.index == value.end_mark.index:
        start = end = text.index(":", key.end_mark.index) + 1
    else:
        start, end = value.start_mark.index, value.end_mark.index
    line_end = text.find("\n", end)
    line_end = len(text) if line_end < 0 else line_end
    comment = text[end:line_end].rstrip("\r")  # whatever followed the value on its line
    rest = text[line_end + 1 :]
    block = _block(regions, key.start_mark.column + 2, newline)
    return text[:start].rstrip(" ") + comment + newline + block + rest


@dataclass(frozen=True)
class _ItemText:
    """Where one item of a block list lies in the text: ``comments`` (the comment lines
    just above its dash) ≤ ``dash`` (the start of its dash's line) < ``end`` (just past its
    own last line, a comment on that line included)."""

    comments: int
    dash: int
    end: int


def _splice_items(
    text: str,
    key: yaml.Node,
    sequence: yaml.SequenceNode,
    regions: list[dict[str, Any]],
    base_dir: Path,
    newline: str,
) -> str:
    """The block list ``sequence`` made ``regions``, item by item (see splice_regions).

    Text between two items that is not an item's comment lines (blank lines, a comment
    set apart by one) goes with the item after it; a new region is written on its own."""
    column = sequence.start_mark.column  # every item's dash is in this column
    items: list[_ItemText] = []
    after = text.find("\n", key.end_mark.index) + 1  # the list starts below its key
    for node in sequence.value:
        dash = _dash_line(text, node.start_mark.index, column)
        items.append(_ItemText(_comments_above(text, dash, after), dash, _end(text, node)))
        after = items[-1].end
    loader = yaml.SafeLoader("")
    old = [loader.construct_object(node, deep=True) for node in sequence.value]
    pieces = [text[: items[0].comments]]
    if not regions:
        pieces.append(_block(regions, column, newline))
    for edit, region in zip(_item_edits(old, regions, base_dir), regions, strict=True):
        if edit is None:  # added
            pieces.append(_block([region], column, newline))
            continue
        item = items[edit.old]
        if edit.old > 0:  # what set it apart from the item before it
            pieces.append(text[items[edit.old - 1].end : item.comments])
        if edit.changed:
            pieces.append(text[item.comments : item.dash] + _block([region], column, newline))
        else:
            pieces.append(text[item.comments : item.end])
    pieces.append(text[items[-1].end :])
    return "".join(pieces)


def _dash_line(text: str, node_start: int, column: int) -> int:
    """The start of the line holding the dash of the item whose content starts at
    ``node_start`` (on the dash's line, or below it after a bare ``-``)."""
    line = text.rfind("\n", 0, node_start) + 1
    while line > 0 and (
        text[line : line + column].strip(" ") or text[line + column : line + column + 1] != "-"
    ):
        line = text.rfind("\n", 0, line - 1) + 1
    return line


def _comments_above(text: str, dash: int, after: int) -> int:
    """The start of the comment lines right above the line at ``dash`` (no blank line
    between), not before ``after``; ``dash`` when there are none."""
    start = dash
    while start > after:
        above = text.rfind("\n", 0, start - 1) + 1
        if not text[above:start].strip().startswith("#"):
            break
        start = above
    return max(start, after)


@dataclass(frozen=True)
class _Edit:
    """What became of an old item: kept as it was, or changed into the new region."""

    old: int  # its index in the file's list
    changed: bool


def _item_edits(
    old: list[Any], regions: list[dict[str, Any]], base_dir: Path
) -> list[_Edit | None]:
    """Per new region, the old item it keeps or changes (None: an added region).

    The longest run of unchanged regions in order is matched first (difflib); in a stretch
    where the old items were replaced, old and new are paired in order as changed items and
    the rest is added or removed.
    """
    old_keys = [region_key(o, base_dir) or f"old {i}" for i, o in enumerate(old)]
    new_keys = [region_key(r, base_dir) or f"new {j}" for j, r in enumerate(regions)]
    edits: list[_Edit | None] = [None] * len(regions)
    matcher = difflib.SequenceMatcher(None, old_keys, new_keys, autojunk=False)
    for tag, i0, i1, j0, j1 in matcher.get_opcodes():
        if tag in ("equal", "replace"):
            # replace: paired in order up to the shorter side
            for i, j in zip(range(i0, i1), range(j0, j1), strict=False):
                edits[j] = _Edit(i, changed=tag == "replace")
    return edits


def region_key(region: Any, base_dir: Path) -> str | None:
    """What a region means, as text: two regions with the same key are the same region
    however they are written (number forms, motion defaults spelled out or not, a mask path
    relative to ``base_dir`` or absolute). None for what is not a valid region."""
    try:
        valid = Region.model_validate(region, context={"base_dir": base_dir})
    except ValueError:
        return None
    return json.dumps(valid.model_dump(mode="json", exclude_none=True), sort_keys=True)


def _end(text: str, node: yaml.Node) -> int:
    """Index just past the last line of ``node``'s own content (not the comments or blank
    lines after it, which a block collection's end mark would include)."""
    while isinstance(node, (yaml.SequenceNode, yaml.MappingNode)) and not node.flow_style:
        if not node.value:
            break
        last = node.value[-1]
        node = last[1] if isinstance(last, tuple) else last
    mark = node.end_mark
    if mark.column == 0:
        return mark.index
    line_end = text.find("\n", mark.index)
    return len(text) if line_end < 0 else line_end + 1


def _block(regions: list[dict[str, Any]], indent: int, newline: str) -> str:
    """The regions as a block list of block mappings; lists and mappings inside a region
    (box, click, motion) in flow style, as people write them."""
    if not regions:
        return " " * indent + "[]" + newline
    flowing = [{key: _Flow(value) if isinstance(value, (list, dict)) else value
                for key, value in region.items()} for region in regions]  # fmt: skip
    dumped = yaml.dump(flowing, Dumper=_RegionDumper, sort_keys=False, allow_unicode=True,
                       width=1 << 16)  # fmt: skip
    return "".join(" " * indent + line + newline for line in dumped.splitlines())


class _Flow:
    """A list or mapping the dumper writes in flow style."""

    def __init__(self, value: list[Any] | dict[str, Any]) -> None:
        self.value = value


class _RegionDumper(yaml.SafeDumper):
    def represent_flow(self, data: _Flow) -> yaml.Node:
        if isinstance(data.value, dict):
            return self.represent_mapping("tag:yaml.org,2002:map", data.value, flow_style=True)
        return self.represent_sequence("tag:yaml.org,2002:seq", data.value, flow_style=True)


_RegionDumper.add_representer(_Flow, _RegionDumper.represent_flow)


# --- preview -----------------------------------------------------------------------------
def render_preview(
    scene: PathLike, regions: list[dict[str, Any]], out_dir: PathLike, width: int = PREVIEW_WIDTH
) -> dict[str, Any]:
    """Animate ``regions`` with the ``flow`` backend at ``width`` as ``pano4d train`` animates
    at its working size (``animate.pipeline.animation_input``: the panorama and the regions
    area-downsampled once) and write the loop as ``out_dir/0000.png`` … (8-bit). Uses the
    scene's frame count, frame rate, border and seed; nothing is written beside scene.yaml."""
    from pano4d.animate.pipeline import animation_input, frame_renderer

    started = time.perf_counter()
    scene = Path(scene).resolve()
    cfg = load_config(scene, require_regions=False)
    edited = edited_config(cfg, scene, regions)
    if width < 64 or width % 2:
        raise EditError(f"the preview width must be an even number ≥ 64, got {width}")
    width = min(width, image_size(cfg.panorama)[0])
    height = width // 2
    flow = edited.animate.model_copy(update={"backend": "flow"})
    edited = edited.model_copy(update={"animate": flow})
    render, _ = frame_renderer(edited, animation_input(edited, (width, height)), None)
    out = Path(out_dir)
    frames = []
    for t in range(cfg.animate.frames):
        path = out / f"{t:04d}.png"
        write_image(path, np.asarray(render(t)))
        frames.append(str(path))
    return {
        "frames": frames,
        "fps": cfg.animate.fps,
        "width": width,
        "height": height,
        "seconds": time.perf_counter() - started,
    }


def edited_config(cfg: SceneConfig, scene: Path, regions: list[dict[str, Any]]) -> SceneConfig:
    """``cfg`` with the edited ``regions`` (validated as scene.yaml's would be)."""
    if not regions:
        raise EditError("there is no region to animate: draw one first")
    items = [_item(r, r.get("mask_png")) for r in regions]
    checked = []
    for index, item in enumerate(items):
        try:
            checked.append(Region.model_validate(item, context={"base_dir": scene.parent}))
        except ValueError as error:
            raise EditError(f"regions[{index}]: {error}") from None
    return cfg.model_copy(update={"regions": checked})
