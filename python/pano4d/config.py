"""scene.yaml: what to animate and lift, validated up front with errors a user can act on.

``load_config(path)`` reads the YAML, resolves every path against the YAML file's folder
(absolute ``Path`` objects afterwards), checks that input files exist, and raises
``ConfigError`` with one line per problem: the file, the key path (``regions[1].box``), the
value given and what was expected. ``templates/scene.yaml`` documents every key.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import operator
import os
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.fields import FieldInfo

from pano4d.errors import InputError
from pano4d.fsutil import write_text_atomic

PathLike = str | os.PathLike[str]
TEMPLATE_PATH = Path(__file__).parent / "templates" / "scene.yaml"

# The lifting phase's knobs per quality preset (their types, meaning and the defaults every
# preset shares: PresetKnobs). draft must finish in minutes on a CPU.
PRESETS: dict[str, dict[str, int | float | bool]] = {
    "draft": {
        "view_size": 128,
        "init_stride": 5,
        "align_iterations": 50,
        "gaussian_iterations": 100,
        "max_gaussians": 100_000,
        "sh_degree": 0,
        "densify": True,
        "lambda_temporal": 0.1,
        "lambda_geo": 0.05,
        "lambda_sem": 0.0,
    },
    "balanced": {
        "view_size": 512,
        "init_stride": 2,
        "align_iterations": 300,
        "gaussian_iterations": 2000,
        "max_gaussians": 1_000_000,
        "sh_degree": 2,
        "densify": True,
        "lambda_temporal": 0.1,
        "lambda_geo": 0.05,
        "lambda_sem": 0.01,
    },
    "max": {
        "view_size": 1024,
        "init_stride": 1,
        "align_iterations": 1000,
        "gaussian_iterations": 10_000,
        "max_gaussians": 4_000_000,
        "sh_degree": 3,
        "densify": True,
        "lambda_temporal": 0.1,
        "lambda_geo": 0.05,
        "lambda_sem": 0.01,
    },
}


class ConfigError(InputError, ValueError):
    """An invalid scene.yaml; the message has one line per problem."""


# Paths are read as plain strings from YAML (strict mode would refuse them otherwise).
LoosePath = Annotated[Path, Field(strict=False)]


class _DynamicOnly:
    """Marks a knob only the dynamic stage reads (``Annotated[type, DYNAMIC_ONLY]``):
    changing it keeps the static set's checkpoint (``lift.checkpoints.stage_keys``)."""


DYNAMIC_ONLY = _DynamicOnly()


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class OptimisationKnobs(BaseModel):
    """How Gaussians are optimised: the loss weights, densification and the learning rates.

    The one definition of these knobs: a preset's (``PresetKnobs``) and each optimisation's
    (``lift.trainer.Knobs``, what both trainers read and the resident one hands to the GPU
    as ``pano4d._core.TrainSettings``) extend it. A default is the term switched off, or the
    value every preset uses; the learning rates are knobs because they are the first thing
    to tune when a scene under- or over-fits in its steps (3DGS exposes the same ones).
    """

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    # L = L_rgb + λ_temporal L_temporal + λ_geo L_geo + λ_sem L_sem,
    # L_rgb = (1 − λ_dssim) L1 + λ_dssim (1 − SSIM)
    lambda_temporal: float = Field(0.0, ge=0)  # weight of L_temporal
    lambda_geo: float = Field(0.0, ge=0)  # weight of L_geo
    lambda_sem: float = Field(0.0, ge=0)  # weight of L_sem (with a feature backend)
    lambda_dssim: float = Field(0.2, ge=0, le=1)  # the D-SSIM share of L_rgb (3DGS's)
    densify: bool = False  # split or clone where the fit is not done, and prune, while training
    # End each warm-started dynamic set once its loss has converged (lift/convergence.py)
    # instead of always at the count; off in every preset until measured at balanced (at
    # draft it saved 10 % of the steps and lost up to 0.5 dB on the frames it stopped early,
    # bench/RESULTS.md).
    stop_when_converged: Annotated[bool, DYNAMIC_ONLY] = False
    # Adam's learning rates; positions move as offsets in units of each Gaussian's initial
    # depth, so one rate fits a Gaussian at 2 m and one at 1000 m.
    lr_position: float = Field(1e-3, ge=0)
    lr_scale: float = Field(5e-3, ge=0)  # of the log-scales
    lr_rotation: float = Field(1e-3, ge=0)  # of the quaternions
    lr_opacity: float = Field(5e-2, ge=0)  # of the opacity logits
    # SH degree 0 (4× 3DGS: our runs are hundreds of steps); the higher degrees take
    # lr_color / 20, as in 3DGS
    lr_color: float = Field(1e-2, ge=0)
    # A spacetime set's (pano4d.spacetime) presence in time: its centre time moves in
    # frames per step; its width's logarithm learns as the log-scales do. Its colour and
    # position terms take lr_color and lr_position.
    lr_time_centre: Annotated[float, DYNAMIC_ONLY] = Field(1e-2, ge=0)
    lr_time_width: Annotated[float, DYNAMIC_ONLY] = Field(5e-3, ge=0)  # of the log-widths
    # Draw every Gaussian through the rasteriser's 2D filter with opacity compensation, in
    # training and in every render of the scene (docs/rasterizer.md): a view of fewer
    # pixels than the training views then shows what a supersampled render would, where
    # the classic mode (false: 3DGS's dilation alone) aliases. The .ply4d records it.
    antialiased: bool = True


class StageKnobs(BaseModel):
    """What the lifting stages are sized by: the views, the initial Gaussians, the steps,
    the budget and the colour's degree (what the presets differ in)."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    view_size: int = Field(ge=16)  # pixels per side of each perspective view (a tile at least)
    init_stride: int = Field(ge=1)  # working-panorama pixels between initial Gaussians
    align_iterations: int = Field(ge=1)  # depth alignment (per-view scale + shift) steps
    gaussian_iterations: int = Field(ge=1)  # optimisation steps per timestamp
    # The share of gaussian_iterations each later timestamp runs: it starts from t − 1's set
    # with the frame's colour change applied (lift/initial.follow_frame_change), so it needs
    # fewer steps than t = 0; lower is faster and less exact (bench/RESULTS.md: "Frames").
    later_iteration_share: Annotated[float, DYNAMIC_ONLY] = Field(0.5, gt=0, le=1)
    max_gaussians: int = Field(ge=1)  # the budget: static plus one timestamp's dynamic set
    sh_degree: int = Field(ge=0, le=3)  # spherical-harmonics degree of the Gaussians' colour
    # How the dynamic stage models time: "per_timestamp" fits one set per timestamp in
    # sequence (warm-started from t − 1); "spacetime" fits one set for every timestamp, each
    # Gaussian with Fourier terms of its colour and position and an opacity over time
    # (pano4d/spacetime.py), stored once in a version-2 .ply4d; "tracked" runs the
    # per-timestamp sequence with one set whose positions and colours alone follow the
    # frames, then stores it as a spacetime set through its poses (the sequence's time,
    # near its quality, a spacetime set's bytes: bench/RESULTS.md, "One dynamic set").
    dynamic_model: Annotated[Literal["per_timestamp", "spacetime", "tracked"], DYNAMIC_ONLY] = (
        "per_timestamp"
    )
    # The spacetime set's Fourier terms per quantity (0: constant in time). A tracked set
    # passes through every frame with ⌊frames / 2⌋ of each (7 for 14 frames); fewer store
    # less and smooth the motion.
    colour_harmonics: Annotated[int, DYNAMIC_ONLY] = Field(2, ge=0, le=8)
    position_harmonics: Annotated[int, DYNAMIC_ONLY] = Field(1, ge=0, le=8)
    # The spacetime stage's steps per step of the static stage (gaussian_iterations): one
    # set trains on every frame's views at once, a step on one (view, time) pair.
    spacetime_step_ratio: Annotated[float, DYNAMIC_ONLY] = Field(2.0, gt=0)
    # A dynamic step renders only the window of each view that the dynamic set can reach,
    # with the static Gaussians that can draw into it (lift/windows.py: the same loss and
    # gradient as the whole view's); false renders whole views, to compare.
    dynamic_windows: Annotated[bool, DYNAMIC_ONLY] = True


class PresetKnobs(OptimisationKnobs, StageKnobs):
    """The lifting phase's knobs: a preset's values with scene.yaml's ``overrides`` applied
    (``SceneConfig.resolved_preset``); the stages' first, then the optimisation's."""


def _absolute(value: Path, info: ValidationInfo) -> Path:
    """Make a path absolute against the YAML file's folder (or the working directory)."""
    base = Path((info.context or {}).get("base_dir", Path.cwd()))
    return (base / value.expanduser()).resolve()


def _existing(value: Path, info: ValidationInfo, kind: Literal["file", "folder"]) -> Path:
    path = _absolute(value, info)
    if not path.exists():
        raise ValueError(f"{kind} not found: {path}")
    if kind == "file" and not path.is_file():
        raise ValueError(f"expected a file, found a folder: {path}")
    if kind == "folder" and not path.is_dir():
        raise ValueError(f"expected a weights folder, found a file: {path}")
    return path


def _input_file(value: Path | None, info: ValidationInfo) -> Path | None:
    return None if value is None else _existing(value, info, "file")


def _weights_folder(value: Path | None, info: ValidationInfo) -> Path | None:
    return None if value is None else _existing(value, info, "folder")


class Motion(_Section):
    """Optional motion hint for a region."""

    direction_deg: float = 0.0  # in the image: 0 = towards +u, 90 = towards the zenith
    speed: float = Field(0.5, ge=0.0)  # degrees of arc per frame


class Region(_Section):
    """One moving region: exactly one of mask / box / click, an optional name and motion."""

    name: str | None = Field(None, min_length=1)  # a label; the region editor shows it
    mask: LoosePath | None = None
    box: list[float] | None = None
    click: list[float] | None = None
    size: int | None = Field(None, gt=0)
    motion: Motion | None = None

    _mask_exists = field_validator("mask")(_input_file)

    @field_validator("box")
    @classmethod
    def _box_shape(cls, box: list[float] | None) -> list[float] | None:
        if box is None:
            return None
        if len(box) != 4:
            raise ValueError("expected 4 numbers [u0, v0, u1, v1]")
        if min(box) < 0:
            raise ValueError("expected pixel coordinates ≥ 0")
        if box[1] >= box[3]:
            raise ValueError("expected v0 < v1 (the box's top above its bottom)")
        if box[0] == box[2]:
            raise ValueError("expected u0 ≠ u1 (u0 > u1 means the box crosses the seam)")
        return box

    @field_validator("click")
    @classmethod
    def _click_shape(cls, click: list[float] | None) -> list[float] | None:
        if click is not None:
            if len(click) != 2:
                raise ValueError("expected 2 numbers [u, v]")
            if min(click) < 0:
                raise ValueError("expected pixel coordinates ≥ 0")
        return click

    @model_validator(mode="after")
    def _exactly_one(self) -> Region:
        given = [key for key in ("mask", "box", "click") if getattr(self, key) is not None]
        if len(given) != 1:
            found = f"got {', '.join(given)}" if given else "got none"
            raise ValueError(f"expected exactly one of mask / box / click, {found}")
        if self.size is not None and self.click is None:
            raise ValueError("'size' only applies to a click region")
        return self

    @property
    def kind(self) -> Literal["mask", "box", "click"]:
        return "mask" if self.mask is not None else "box" if self.box is not None else "click"

    def pixel_box(self, width: int, height: int) -> tuple[float, float, float, float]:
        """The region's box (u0, v0, u1, v1) in pixels; u0 > u1 crosses the seam.

        A click becomes a ``size``-pixel square (default 256) centred on it, wrapped in u
        and clipped in v. Raises ConfigError for mask regions and for boxes off the image.
        """
        if self.box is not None:
            u0, v0, u1, v1 = self.box
            if max(u0, u1) > width or v1 > height:
                raise ConfigError(f"box {self.box} lies outside the {width}×{height} panorama")
            return (u0, v0, u1, v1)
        if self.click is not None:
            u, v = self.click
            if u > width or v > height:
                raise ConfigError(f"click {self.click} lies outside the {width}×{height} panorama")
            half = (self.size or 256) / 2
            if 2 * half >= width:
                return (0.0, max(0.0, v - half), float(width), min(float(height), v + half))
            return ((u - half) % width, max(0.0, v - half), (u + half) % width,
                    min(float(height), v + half))  # fmt: skip
        raise ConfigError("a mask region has no box; use pano4d.regions.region_mask()")


class AnimateConfig(_Section):
    """Animating phase: the image-to-video backend and its sampling knobs."""

    backend: Literal["flow", "svd"] = "flow"
    weights: LoosePath | None = None
    frames: int = Field(14, ge=2)
    steps: int = Field(25, ge=1)
    fps: float = Field(7.0, gt=0)
    motion_bucket: int = Field(127, ge=0, le=255)
    noise_aug: float = Field(0.02, ge=0)
    guidance_min: float = Field(1.0, ge=0)
    guidance_max: float = Field(3.0, ge=0)
    views: int = Field(20, ge=1)
    fov_deg: float = Field(80.0, gt=0, lt=180)
    dtype: Literal["auto", "float32", "float16", "bfloat16"] = "auto"
    border_px: int = Field(16, ge=0)

    _weights_exist = field_validator("weights")(_weights_folder)

    @model_validator(mode="after")
    def _needs(self) -> AnimateConfig:
        if self.backend == "svd" and self.weights is None:
            raise ValueError(
                "backend 'svd' needs 'weights': a local folder with the diffusers model"
            )
        if self.guidance_min > self.guidance_max:
            raise ValueError(
                f"expected guidance_min ≤ guidance_max, got {self.guidance_min} > "
                f"{self.guidance_max}"
            )
        return self


class DepthConfig(_Section):
    """Depth for lifting: the layout prior, a depth file (ray length), or a DPT model."""

    backend: Literal["layout", "file", "dpt"] = "layout"
    path: LoosePath | None = None
    weights: LoosePath | None = None
    camera_height: float = Field(1.6, gt=0)
    far: float = Field(1000.0, gt=0)

    _path_exists = field_validator("path")(_input_file)
    _weights_exist = field_validator("weights")(_weights_folder)

    @model_validator(mode="after")
    def _needs(self) -> DepthConfig:
        if self.backend == "file" and self.path is None:
            raise ValueError("backend 'file' needs 'path': an EXR or 16-bit PNG depth map")
        if self.backend == "dpt" and self.weights is None:
            raise ValueError("backend 'dpt' needs 'weights': a local folder with the model")
        return self


class FeaturesConfig(_Section):
    """Feature model for the semantic loss (none disables it)."""

    backend: Literal["none", "dinov2"] = "none"
    weights: LoosePath | None = None

    _weights_exist = field_validator("weights")(_weights_folder)

    @model_validator(mode="after")
    def _needs(self) -> FeaturesConfig:
        if self.backend == "dinov2" and self.weights is None:
            raise ValueError("backend 'dinov2' needs 'weights': a local folder with the model")
        return self


class LiftConfig(_Section):
    """Lifting phase view layout."""

    views: int = Field(20, ge=1)
    fov_deg: float = Field(80.0, gt=0, lt=180)


class SceneConfig(_Section):
    """A whole scene.yaml; paths are absolute after validation."""

    panorama: LoosePath
    regions: list[Region]
    animate: AnimateConfig = AnimateConfig()
    depth: DepthConfig = DepthConfig()
    features: FeaturesConfig = FeaturesConfig()
    lift: LiftConfig = LiftConfig()
    preset: Literal["draft", "balanced", "max"] = "balanced"
    overrides: dict[str, Any] = {}
    seed: int = Field(0, ge=0)
    output: LoosePath = Field(Path("output"), validate_default=True)
    device: Literal["auto", "cpu", "cuda"] = "auto"

    _panorama_exists = field_validator("panorama")(_input_file)
    _output_absolute = field_validator("output")(_absolute)

    @field_validator("regions")
    @classmethod
    def _some_regions(cls, regions: list[Region], info: ValidationInfo) -> list[Region]:
        # The region editor opens a scene before it has regions; nothing else may.
        if not regions and (info.context or {}).get("require_regions", True):
            raise ValueError("a scene needs at least one moving region (a mask, box or click)")
        return regions

    @field_validator("overrides")
    @classmethod
    def _known_overrides(cls, overrides: dict[str, Any]) -> dict[str, Any]:
        knobs = PresetKnobs.model_fields
        problems = []
        for key, value in overrides.items():
            shown = _show(value)
            if key not in knobs:
                problems.append(f"unknown knob '{key}' (got {shown}){_suggest(key, knobs)}")
                continue
            expected = knobs[key].annotation
            if typing.get_origin(expected) is Literal:  # one of some words
                choices = typing.get_args(expected)
                if value not in choices:
                    *others, last = (repr(c) for c in choices)
                    words = f"{', '.join(others)} or {last}" if others else last
                    problems.append(f"'{key}' expects {words}, got {shown}")
            elif type(value) is not expected and not (expected is float and type(value) is int):
                problems.append(f"'{key}' expects {_TYPE_WORDS[expected]}, got {shown}")
            elif bounds := _outside_bounds(knobs[key], value):
                problems.append(f"'{key}' expects a value {bounds}, got {shown}")
        if problems:
            raise ValueError("; ".join(problems))
        return overrides

    def resolved_preset(self, panorama_width: int | None = None) -> PresetKnobs:
        """The preset's knobs with ``overrides`` applied. Given the panorama's width, the
        view size is capped where a view pixel matches a panorama pixel: larger views cost
        time and only resample the same pixels."""
        knobs = dict(PRESETS[self.preset])
        for key, value in self.overrides.items():
            if key not in PresetKnobs.model_fields:
                raise ConfigError(
                    f"unknown override '{key}'{_suggest(key, PresetKnobs.model_fields)}"
                )
            knobs[key] = value
        if panorama_width is not None:
            from pano4d.sphere import matched_view_size

            matched = matched_view_size(panorama_width, self.lift.fov_deg)
            knobs["view_size"] = min(int(knobs["view_size"]), matched)
        return PresetKnobs(**knobs)


_TYPE_WORDS = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}
# A knob's bounds (its Field's gt/ge/lt/le) in words, with the test each one makes.
_BOUNDS = {"gt": (">", operator.gt), "ge": ("≥", operator.ge),
           "lt": ("<", operator.lt), "le": ("≤", operator.le)}  # fmt: skip


def _outside_bounds(field: FieldInfo, value: float) -> str | None:
    """The field's bounds in words ("≥ 0 and ≤ 3") when ``value`` breaks one, else None."""
    bounds = [(sign, holds, getattr(m, name)) for m in field.metadata
              for name, (sign, holds) in _BOUNDS.items()
              if getattr(m, name, None) is not None]  # fmt: skip
    if all(holds(value, bound) for _, holds, bound in bounds):
        return None
    return " and ".join(f"{sign} {bound}" for sign, _, bound in bounds)


# --- loading ----------------------------------------------------------------------------
class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice (PyYAML silently keeps the last one)."""


def _mapping_without_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode) -> Any:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node)
        if key in seen:
            mark = key_node.start_mark
            raise yaml.constructor.ConstructorError(
                None, None, f"key '{key}' appears twice in one mapping", mark
            )
        seen.add(key)
    return loader.construct_mapping(node)


_UniqueKeyLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_without_duplicates
)


def load_config(path: PathLike, require_regions: bool = True) -> SceneConfig:
    """Read and validate a scene.yaml; raises ConfigError naming the file and every problem.

    ``require_regions=False`` accepts an empty ``regions: []`` (for the region editor)."""
    path = Path(path).resolve()
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=_UniqueKeyLoader)
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "unknown place"
        problem = error.problem or error.context or "invalid YAML"
        context = error.context_mark
        if error.context and context is not None and context is not mark:
            problem += f" ({error.context} at line {context.line + 1}, column {context.column + 1})"
        raise ConfigError(f"{path}: malformed YAML at {where}: {problem}") from None
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: malformed YAML: {error}") from None
    if data is None:
        raise ConfigError(f"{path}: the file is empty; it needs at least panorama and regions")
    if not isinstance(data, dict):
        raise ConfigError(
            f"{path}: expected a mapping of keys (panorama, regions, ...), "
            f"got {type(data).__name__}"
        )
    return validate_config(data, base_dir=path.parent, source=path, require_regions=require_regions)


def validate_config(
    data: dict[str, Any],
    base_dir: PathLike,
    source: PathLike | None = None,
    require_regions: bool = True,
) -> SceneConfig:
    """Validate an already-parsed config; relative paths resolve against ``base_dir``."""
    context = {"base_dir": Path(base_dir), "require_regions": require_regions}
    try:
        return SceneConfig.model_validate(data, context=context)
    except ValidationError as error:
        name = str(source) if source is not None else "config"
        lines = [f"{name}: {line}" for line in _describe(error)]
        raise ConfigError("\n".join(lines)) from None


def config_hash(cfg: SceneConfig) -> str:
    """sha256 of the normalised config (defaults filled, absolute paths, sorted keys)."""
    text = json.dumps(cfg.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def write_example(path: PathLike, panorama: str | None = None, force: bool = False) -> Path:
    """Write the commented template scene.yaml; refuses to overwrite unless ``force``."""
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path} already exists; pass force=True to overwrite it")
    text = TEMPLATE_PATH.read_text(encoding="utf-8")
    if panorama is not None:
        text = text.replace("panorama: panorama.png", f"panorama: {json.dumps(str(panorama))}", 1)
    write_text_atomic(path, text)
    return path


# --- error formatting -------------------------------------------------------------------
_EXPECTED = {
    "int_type": "an integer",
    "int_from_float": "an integer",
    "int_parsing": "an integer",
    "float_type": "a number",
    "float_parsing": "a number",
    "bool_type": "true or false",
    "string_type": "a string",
    "list_type": "a list",
    "dict_type": "a mapping of keys",
    "model_type": "a mapping of keys",
    "path_type": "a path",
}


def _describe(error: ValidationError) -> list[str]:
    lines = []
    for item in error.errors(include_url=False):
        kind, loc, value, ctx = item["type"], item["loc"], item.get("input"), item.get("ctx") or {}
        if kind == "extra_forbidden":
            parent, key = loc[:-1], str(loc[-1])
            fields = _fields_at(parent)
            where = _key_path(parent) or "top level"
            lines.append(f"{where}: unknown key '{key}'{_suggest(key, fields)}")
            continue
        where = _key_path(loc) or "top level"
        if kind == "missing":
            lines.append(f"{where}: required key is missing")
        elif kind in _EXPECTED:
            hint = ""
            if kind.startswith("float") and _parses_as_float(value):
                hint = f" (YAML reads {value} as text: write it unquoted, with a dot, as 1.0e3)"
            lines.append(f"{where}: expected {_EXPECTED[kind]}{hint}, got {_show(value)}")
        elif kind == "literal_error":
            lines.append(f"{where}: expected one of {ctx['expected']}, got {_show(value)}")
        elif kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
            op = {"greater_than": ">", "greater_than_equal": "≥", "less_than": "<",
                  "less_than_equal": "≤"}[kind]  # fmt: skip
            bound = next(iter(ctx.values()))
            lines.append(f"{where}: expected a value {op} {bound}, got {_show(value)}")
        elif kind in ("value_error", "assertion_error"):
            message = str(ctx.get("error", item["msg"]))
            shown = "" if "got " in message else f", got {_show(value)}"
            lines.append(f"{where}: {message}{shown}")
        else:
            lines.append(f"{where}: {item['msg'].lower()}, got {_show(value)}")
    return lines


def _parses_as_float(value: Any) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return False
    return isinstance(value, str)


def _key_path(loc: tuple[int | str, ...]) -> str:
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


def _show(value: Any) -> str:
    if isinstance(value, dict) and len(json.dumps(value, default=str)) > 80:
        return "{" + ", ".join(f"{k}: ..." for k in value) + "}"
    return json.dumps(value, default=str) if not isinstance(value, str) else repr(value)


def _suggest(key: str, candidates: typing.Iterable[str]) -> str:
    candidates = list(candidates)
    match = difflib.get_close_matches(key, candidates, n=1, cutoff=0.6)
    if match:
        return f" — did you mean '{match[0]}'?"
    return f"; known keys: {', '.join(candidates)}" if candidates else ""


def _fields_at(loc: tuple[int | str, ...]) -> list[str]:
    """The keys the model at ``loc`` accepts (walking SceneConfig's field annotations)."""
    model: type[BaseModel] = SceneConfig
    for part in loc:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(str(part))
        found = _model_in(field.annotation) if field is not None else None
        if found is None:
            return []
        model = found
    return list(model.model_fields)


def _model_in(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    origin = typing.get_origin(annotation)
    if origin in (list, typing.Union, types.UnionType, Annotated):
        for arg in typing.get_args(annotation):
            found = _model_in(arg)
            if found is not None:
                return found
    return None
