"""The ``pano4d`` command line. Each command is a thin layer over the library.

Every command runs under one error policy (``Commands.invoke``): bad input
(``pano4d.errors.InputError``) and operating-system errors (a missing file, a full disk) print
one line naming the file, key or value and what was expected, exit code 2; any other
exception is a bug in pano4d: one line, exit code 1, and the traceback with
``pano4d --debug <command>``.
"""

from __future__ import annotations

import sys
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer
from rich.console import Console
from typer.core import TyperGroup

from pano4d.errors import InputError, fail
from pano4d.lift.checkpoints import CHECKPOINT_EVERY
from pano4d.region_cli import app as regions_app

if TYPE_CHECKING:
    from pano4d.live import LiveView

console = Console(stderr=True)
Backend = Literal["wgpu", "torch"]


def describe(error: OSError) -> str:
    """An operating-system error as "file: what happened"."""
    if error.filename is None:
        return str(error)
    return f"{error.filename}: {error.strerror or error}"


@contextmanager
def reported_errors(ctx: typer.Context) -> Iterator[None]:
    """Known errors → one line and exit 2; anything else → one line and exit 1, with the
    traceback under ``--debug``."""
    try:
        yield
    except (typer.Exit, typer.Abort, typer.TyperException):
        raise  # typer's own exits and usage errors
    except InputError as error:
        fail(str(error))
    except OSError as error:
        fail(describe(error))
    except Exception as error:
        if ctx.meta.get("pano4d.debug"):
            traceback.print_exception(error)
            hint = "the traceback is above"
        else:
            hint = f"run `pano4d --debug {ctx.invoked_subcommand} …` for the traceback"
        what = " ".join(f"{type(error).__name__}: {error}".split())
        fail(f"internal error (a bug in pano4d; please report it): {what}; {hint}", code=1)


class Commands(TyperGroup):
    """The command group: every command runs under ``reported_errors``."""

    def invoke(self, ctx: typer.Context) -> Any:
        with reported_errors(ctx):
            return super().invoke(ctx)


app = typer.Typer(
    cls=Commands,
    name="pano4d",
    help=(
        "Turn one 360° panorama into a 4D Gaussian scene you can walk through and watch move.\n\n"
        "Start with `pano4d synth demo/` for a synthetic scene with ground truth, or "
        "`pano4d init scene.yaml` to describe your own panorama."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(regions_app)


@app.callback()
def options(
    ctx: typer.Context,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the traceback of an internal error.")
    ] = False,
) -> None:
    ctx.meta["pano4d.debug"] = debug


@app.command()
def init(
    path: Annotated[Path, typer.Argument(help="Where to write the example scene.yaml.")] = Path(
        "scene.yaml"
    ),
    panorama: Annotated[
        str | None, typer.Option(help="Panorama path to put in the file (relative to it).")
    ] = None,
    force: Annotated[bool, typer.Option(help="Overwrite an existing file.")] = False,
) -> None:
    """Write a commented example scene.yaml: every key, its default and its meaning."""
    from pano4d import config

    if path.exists() and not force:
        fail(f"{path} exists; pass --force to overwrite it")
    written = config.write_example(path, panorama=panorama, force=force)
    console.print(f"wrote {written} — edit `panorama` and `regions`, then run pano4d train {path}")


@app.command()
def check(
    scene: Annotated[Path, typer.Argument(help="The scene.yaml to validate.")],
) -> None:
    """Validate a scene.yaml, its panorama and regions; print what it resolves to."""
    from pano4d import config
    from pano4d.images import read_panorama
    from pano4d.regions import region_masks

    cfg = config.load_config(scene)
    height, width = read_panorama(cfg.panorama).shape[:2]
    region_masks(cfg, width, height)  # every region on the panorama, every mask readable
    console.print(
        f"[green]ok[/] {scene}: panorama {cfg.panorama}, {len(cfg.regions)} region(s), "
        f"preset {cfg.preset}"
    )
    preset = cfg.resolved_preset().model_dump()
    for key, value in cfg.resolved_preset(width).model_dump().items():
        note = f"  (the preset's {preset[key]}, capped at the panorama's pixel)"
        console.print(f"  {key} = {value}{note if value != preset[key] else ''}")


def synth_height(width: int, height: int | None) -> int:
    """The height of a synthetic panorama (default width / 2); refuses all but 2:1, and a
    panorama smaller than what ``pano4d train`` reads."""
    from pano4d.images import PANORAMA_MIN_HEIGHT, PANORAMA_MIN_WIDTH, below_panorama_minimum

    height = height if height is not None else width // 2
    if width != 2 * height:
        fail(f"--width must be twice --height for an equirect panorama, got {width}x{height}")
    if below_panorama_minimum(width, height):
        fail(
            f"--width {width}: a {width}x{height} panorama is smaller than the "
            f"{PANORAMA_MIN_WIDTH}x{PANORAMA_MIN_HEIGHT} that pano4d train reads; "
            f"use --width {PANORAMA_MIN_WIDTH} or more"
        )
    return height


@app.command()
def synth(
    out: Annotated[Path, typer.Argument(help="Output folder.")],
    width: Annotated[int, typer.Option(help="Panorama width (height is width / 2).")] = 2048,
    height: Annotated[int | None, typer.Option(help="Panorama height (default width / 2).")] = None,
    frames: Annotated[int, typer.Option(min=1, help="Number of animated frames L.")] = 14,
    seed: Annotated[int, typer.Option(help="Random seed: same seed, same scene.")] = 0,
    views: Annotated[int, typer.Option(help="Ground-truth novel views to render.")] = 8,
    kind: Annotated[
        str, typer.Option(help="Scene kind: landscape (outdoor) or room (indoor).")
    ] = "landscape",
) -> None:
    """Write a synthetic scene with exact depth, motion mask, animation and test views."""
    from pano4d import synth as synth_mod
    from pano4d.synth.scene import SCENE_KINDS

    if kind not in SCENE_KINDS:
        fail(f"--kind must be one of {', '.join(SCENE_KINDS)}, got {kind!r}")
    path = synth_mod.run_synth(out, width, synth_height(width, height), frames, seed, views, kind)
    console.print(f"wrote {path}")


@app.command()
def animate(
    scene: Annotated[Path, typer.Argument(help="The scene.yaml.")],
    frames_out: Annotated[
        Path | None,
        typer.Option(help="Also write every frame whole into this folder (0000.png …)."),
    ] = None,
) -> None:
    """Animating phase alone: the panoramic video in OUTPUT/animate (resumes after a kill)."""
    from pano4d.animate.pipeline import run_animate
    from pano4d.config import load_config

    result = run_animate(load_config(scene))
    console.print(f"[green]animate:[/] {result.store.count} frames in {result.store.folder}")
    if frames_out is not None:
        written = result.store.export(frames_out)
        console.print(f"wrote {len(written)} whole frames into {frames_out}")


@app.command("eval")
def evaluate(
    scene: Annotated[Path, typer.Argument(help="The scene.yaml whose animation to measure.")],
) -> None:
    """Measure an animation: seam, static-region, motion, flicker and loop figures."""
    from pano4d import metrics
    from pano4d.animate.pipeline import animate_folder, frame_store, print_metrics
    from pano4d.config import load_config
    from pano4d.images import read_panorama
    from pano4d.regions import build_regions

    cfg = load_config(scene)
    store = frame_store(cfg)
    # The animating phase's frames, or whole frames put in output/animate/frames by hand.
    frames = store.folder if store.box_path.is_file() else animate_folder(cfg) / "frames"
    if not any(frames.glob("*.png")) and not any(frames.glob("*.exr")):
        fail(f"no frames in {frames}; run `pano4d animate {scene}` first")
    panorama = read_panorama(cfg.panorama)
    regions = build_regions(cfg, panorama.shape[1], panorama.shape[0])
    print_metrics(console, metrics.evaluate_frames(frames, panorama, regions.mask.numpy()))


@app.command()
def export(
    scene: Annotated[Path, typer.Argument(help="The .ply4d scene.")],
    out: Annotated[Path, typer.Argument(help="The file to write (with --sequence: a new folder).")],
    time: Annotated[
        float | None,
        typer.Option(
            "--time",
            "-t",
            help="Scene time in frames, any real ≥ 0, looping (default 0): a version-2 scene "
            "evaluated there, a version-1 one at the timestamp it holds.",
        ),
    ] = None,
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format",
            help="ply | compressed-ply | spz | sog | splat (default: from OUT's ending, else ply).",
        ),
    ] = None,
    sequence: Annotated[
        bool,
        typer.Option(help="Every timestamp, as OUT/frame_0000.<ext>… (SuperSplat's timeline)."),
    ] = False,
) -> None:
    """Write the scene at one time (static + dynamic Gaussians), or every timestamp, as
    splats other tools open: plain 3DGS .ply, SuperSplat .compressed.ply, SPZ, SOG (.sog) or
    .splat."""
    from pano4d import ply4d, share_formats
    from pano4d.progress import Bars

    num_times = ply4d.open(scene).num_times if sequence else 1
    with Bars(enabled=sequence, transient=True, console=console) as bars:
        times = bars.task("exporting", num_times)
        written = share_formats.export(scene, out, fmt, time, sequence, times.advance)
    what = f"{len(written)} timestamps" if sequence else f"time {time or 0:g}"
    console.print(f"wrote {out} ({what})")


Rate = Annotated[
    float | None,
    typer.Option(
        help="Samples a second of scene time (default: the scene's own fps): a version-2 "
        "scene is sent evaluated at each; a version-1 one sends each timestamp shown once."
    ),
]


@app.command()
def serve(
    scene: Annotated[Path, typer.Argument(help="The .ply4d scene.")],
    port: Annotated[int, typer.Option(help="Port of the viewer.")] = 8080,
    host: Annotated[
        str, typer.Option(help="Address to listen on (0.0.0.0: every interface).")
    ] = "127.0.0.1",
    rate: Rate = None,
) -> None:
    """A live 4D viewer in the browser (viser): time slider, play / pause, camera presets."""
    import time as clock

    from pano4d import web
    from pano4d.progress import Bars

    scene_file = web.open_checked(scene)
    plan = web.playback(scene_file, rate)
    with Bars(transient=True, console=console) as bars:
        sets = bars.task("sending the scene", len(plan.set_times) + 1)
        server, _ = web.start_server(scene_file, plan, host, port, on_set=sets.advance)
    port = server.get_port()
    console.print(f"[green]serve:[/] {scene} at http://{host}:{port} (Ctrl+C stops)")
    console.print(web.forwarding_hint(host, port))
    try:
        while True:
            clock.sleep(3600)
    finally:
        server.stop()


@app.command()
def web(
    scene: Annotated[Path, typer.Argument(help="The .ply4d scene.")],
    out: Annotated[Path, typer.Argument(help="The folder to write (new or empty).")],
    rate: Rate = None,
) -> None:
    """The scene as a static web page folder (viser's client + a recording): OUT/index.html."""
    from pano4d import web as web_mod
    from pano4d.progress import Bars

    scene_file = web_mod.open_checked(scene)
    plan = web_mod.playback(scene_file, rate)
    with Bars(transient=True, console=console) as bars:
        sets = bars.task("recording the scene", len(plan.set_times) + 1)
        web_mod.write_web(scene_file, plan, out, on_set=sets.advance)
    console.print(
        f"wrote {out}: serve the folder with any file server "
        f"(python -m http.server -d {out}) and open index.html"
    )


@app.command()
def info() -> None:
    """Show the version and the GPU adapter the rasteriser uses (PANO4D_ADAPTER forces one)."""
    import pano4d
    from pano4d.renderer import adapter_info

    console.print(f"pano4d {pano4d.__version__}")
    try:
        adapter = adapter_info()
    except RuntimeError as e:  # the machine has no adapter pano4d can use: its setup to fix
        raise InputError(f"no wgpu adapter: {e} (the torch backend still works)") from e
    for key, value in adapter.items():
        console.print(f"  {key}: {value}")


@app.command("render")
def render_command(
    scene: Annotated[Path, typer.Argument(help="A .ply4d scene or a plain 3DGS .ply.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output .png (or .mp4 with --path).")],
    camera: Annotated[
        str | None,
        typer.Option(
            help="Camera as JSON, or a JSON file: {position, forward, fov_deg[, up]} (the viewer's "
            "'copy pose') or {K, world_to_cam, width, height}. Default: the panorama's viewpoint."
        ),
    ] = None,
    time: Annotated[
        float | None,
        typer.Option(
            "--time",
            "-t",
            help="Scene time in frames, any real ≥ 0, looping: a still's, or where a video "
            "starts (.ply4d; a .ply: 0).",
        ),
    ] = None,
    width: Annotated[
        int | None,
        typer.Option(help="Image width (default 1280; 4096 with --projection equirect)."),
    ] = None,
    height: Annotated[
        int | None,
        typer.Option(
            help="Image height (default 720; equirect: width / 2, or the whole top-bottom "
            "stereo frame, width by default)."
        ),
    ] = None,
    path: Annotated[
        str | None,
        typer.Option(
            help="Render a video instead: turntable | fly-through | a nerfstudio "
            "camera_path.json (its size, fps, poses, fov and render_time; README, 'Camera paths')."
        ),
    ] = None,
    path_transform: Annotated[
        Path | None,
        typer.Option(
            help="nerfstudio's dataparser_transforms.json: maps a camera_path.json made in "
            "nerfstudio on `pano4d views`' dataset back to the scene's coordinates."
        ),
    ] = None,
    frames: Annotated[
        int | None,
        typer.Option(help="Video length in frames (default 120; a 360° video: one loop)."),
    ] = None,
    fps: Annotated[
        float | None,
        typer.Option(help="Video frame rate (default 30); scene time plays at the scene's own."),
    ] = None,
    projection: Annotated[
        str,
        typer.Option(help="perspective | equirect (a 360° still, or a video with .mp4)."),
    ] = "perspective",
    stereo: Annotated[
        str | None,
        typer.Option(help="top-bottom: omnidirectional stereo, left eye on top (equirect)."),
    ] = None,
    ipd: Annotated[
        float | None,
        typer.Option(
            help="Stereo eye distance in scene units (default: 0.064/1.6 of the eye's "
            "height above the ground, 1.6 m read as the eye height)."
        ),
    ] = None,
    backend: Annotated[Backend, typer.Option(help="Rasteriser.")] = "wgpu",
) -> None:
    """Render views of a scene headless, through the same rasteriser as training:
    perspective stills and camera paths, 360° equirect stills and videos (mono or stereo)."""
    from pano4d import camera_paths, panorama_video
    from pano4d.progress import Bars

    if projection not in ("perspective", "equirect"):
        fail(f"--projection must be 'perspective' or 'equirect', got {projection!r}")
    if stereo not in (None, "top-bottom"):
        fail(f"--stereo must be 'top-bottom' (left eye on top), got {stereo!r}")
    if stereo is not None and projection != "equirect":
        fail("--stereo top-bottom renders a 360° frame: add --projection equirect")
    if ipd is not None and stereo is None:
        fail(f"--ipd {ipd} sets the stereo eye distance: add --stereo top-bottom")
    if path is not None and path.endswith(".json"):
        given = {"--camera": camera, "--time": time, "--width": width, "--height": height,
                 "--frames": frames, "--fps": fps}  # fmt: skip
        for name, value in given.items():
            if value is not None:
                fail(f"{name}: {path} sets the video's cameras, size, length and rate")
        drawn = render_camera_path_file(scene, Path(path), path_transform, out, projection,
                                        stereo is not None, ipd, backend)  # fmt: skip
        console.print(f"wrote {out} ({drawn})")
        return
    if path_transform is not None:
        fail(f"--path-transform {path_transform} maps a camera_path.json: add --path FILE.json")
    fps = 30.0 if fps is None else fps
    time = 0.0 if time is None else time
    if projection == "equirect":
        # Defaults: 4096 wide; a mono frame 2:1, a stereo frame square (two 2:1 eyes).
        w = width if width is not None else 4096 if stereo or height is None else 2 * height
        h = height if height is not None else (w if stereo else w // 2)
        frame = panorama_video.Frame360(w, h, stereo is not None, ipd)
        with Bars(transient=True, console=console) as bars:
            drawn = panorama_video.render_360(
                scene, out, frame, time, path, frames, fps, backend=backend, bars=bars
            )
        eyes = f", IPD {drawn.ipd:.4g} scene units" if drawn.ipd is not None else ""
        console.print(f"wrote {out} ({w}x{h} equirect{', top-bottom stereo' if stereo else ''}"
                      f"{eyes})")  # fmt: skip
        return
    w = 1280 if width is None else width
    h = 720 if height is None else height
    if path is None:
        cam = camera_paths.parse_camera(camera, w, h)
        camera_paths.render_still(scene, cam, time, out, backend=backend)
    else:
        count = 120 if frames is None else frames
        camera_paths.render_path(scene, path, out, w, h, count, fps, time, backend=backend)
    console.print(f"wrote {out}")


def render_camera_path_file(
    scene: Path,
    path_file: Path,
    transform_file: Path | None,
    out: Path,
    projection: str,
    stereo: bool,
    ipd: float | None,
    backend: str,
) -> str:
    """``pano4d render --path camera_path.json``: the video the file describes (its
    ``camera_type`` decides perspective or 360°); returns what was drawn, in words."""
    from pano4d import camera_paths, nerfstudio_path, panorama_video
    from pano4d.progress import Bars

    path = nerfstudio_path.read(path_file)
    if transform_file is not None:
        path = path.to_scene(nerfstudio_path.read_dataparser_transform(transform_file))
    size = f"{len(path.frames)} frames, {path.width}x{path.height} at {path.fps:g} fps"
    if path.camera_type == "equirectangular":
        with Bars(transient=True, console=console) as bars:
            drawn = panorama_video.render_360_path(scene, path, out, stereo, ipd, backend, bars)
        eyes = f", top-bottom stereo, IPD {drawn.ipd:.4g} scene units" if stereo else ""
        return f"{size}, equirect{eyes}"
    if projection == "equirect" or stereo:
        fail(f"--projection equirect: {path_file} is a perspective camera path (camera_type)")
    camera_paths.render_camera_path(scene, path, out, backend=backend)
    return size


@app.command()
def train(
    scene: Annotated[Path, typer.Argument(help="The scene.yaml.")],
    backend: Annotated[Backend, typer.Option(help="Rasteriser.")] = "wgpu",
    trainer: Annotated[
        str | None,
        typer.Option(
            help="resident: the Gaussians, losses and Adam stay on the GPU (default with "
            "wgpu); torch: the torch reference, losses and Adam on the host (the only choice "
            "with --backend torch)."
        ),
    ] = None,
    checkpoint_every: Annotated[
        int, typer.Option(min=1, help="Optimisation steps between checkpoints.")
    ] = CHECKPOINT_EVERY,
    serve: Annotated[
        bool,
        typer.Option(
            "--serve",
            help="Show the Gaussians in the browser as they train (viser, as pano4d serve), "
            "refreshed at every checkpoint; the server stops when training ends.",
        ),
    ] = False,
    port: Annotated[
        int | None,
        typer.Option(min=1, max=65535, help="Port of the live view (with --serve; default 8080)."),
    ] = None,
    host: Annotated[
        str | None,
        typer.Option(
            help="Address the live view listens on (with --serve; default 127.0.0.1, "
            "0.0.0.0: every interface)."
        ),
    ] = None,
) -> None:
    """Both phases end to end: animate, align depth, fit Gaussians, write OUTPUT/scene.ply4d.

    Checkpoints after every stage; run the same command again to resume after a kill."""
    from pano4d.config import load_config
    from pano4d.lift.trainers import trainer_for
    from pano4d.train import run_train

    for name, value in (("--port", port), ("--host", host)):
        if value is not None and not serve:
            fail(f"{name} {value} is the live view's: add --serve")
    cfg = load_config(scene)
    try:
        kind = trainer_for(backend, trainer)
    except ValueError as e:
        fail(f"--trainer: {e}")
    host = "127.0.0.1" if host is None else host
    with live_view(serve, host, 8080 if port is None else port, checkpoint_every) as live:
        metrics = run_train(
            cfg, render_backend=backend, trainer=kind, checkpoint_every=checkpoint_every,
            on_snapshot=None if live is None else live.show,
        )  # fmt: skip
    output = Path(cfg.output)
    print_run_table(metrics, output, "pano4d train")
    if serve:
        console.print(  # one line, whatever the width: scripts and tests read it
            f"the live view has stopped; pano4d serve {output / 'scene.ply4d'} shows the result",
            soft_wrap=True,
        )


@contextmanager
def live_view(
    serve: bool, host: str, port: int, checkpoint_every: int
) -> Iterator[LiveView | None]:
    """``pano4d train --serve``'s live view (``pano4d.live.LiveView``) for the length of the
    block, its address printed before training starts; None without --serve."""
    if not serve:
        yield None
        return
    from pano4d import live, web

    with live.serving(host, port) as view:
        console.print(
            f"[green]live view:[/] http://{host}:{port} (the Gaussians as they train, "
            f"refreshed every {checkpoint_every} steps; it stops when training ends)",
            soft_wrap=True,
        )
        console.print(web.forwarding_hint(host, port), soft_wrap=True)
        yield view


@app.command()
def views(
    scene: Annotated[Path, typer.Argument(help="The scene.yaml.")],
    out: Annotated[Path, typer.Argument(help="Output folder of the dataset.")],
    time: Annotated[int, typer.Option("--time", "-t", help="Timestamp index.")] = 0,
) -> None:
    """The lifting phase's views of one timestamp as a dataset other trainers read: nerfstudio
    transforms.json, COLMAP text model, images, aligned depth, moving-region masks, points.

    Runs the depth and alignment stages through the scene's checkpoints (read back after a
    `pano4d train`). All views share one centre: use transforms.json's scene_scale in place of
    a trainer's automatic scale (README, "Other trainers")."""
    from pano4d.config import load_config
    from pano4d.lift.views_export import export_views

    dataset = export_views(load_config(scene), out, time)
    console.print(
        f"[green]views:[/] {dataset.views} views of t={dataset.time}, {dataset.points} points, "
        f"scene_scale {dataset.scene_scale:.4g} in {dataset.folder}"
    )


@app.command()
def batch(
    scenes: Annotated[
        list[Path],
        typer.Argument(help="scene.yaml files, folders of them, or list files (one a line)."),
    ],
    address: Annotated[
        str | None,
        typer.Option(
            help="Join this Ray cluster (`ray start --head` there; `auto`: this machine's). "
            "Default: a local Ray instance for this batch."
        ),
    ] = None,
    gpus_per_scene: Annotated[
        float, typer.Option(help="GPUs per scene; with no GPU in the cluster, CPU slots.")
    ] = 1.0,
    cpus_per_scene: Annotated[float, typer.Option(help="CPUs per scene.")] = 1.0,
    backend: Annotated[str, typer.Option(help="Rasteriser: wgpu | torch.")] = "wgpu",
    report: Annotated[Path, typer.Option(help="Where to write the table as JSON.")] = Path(
        "batch.json"
    ),
) -> None:
    """Train many scenes, one Ray task each; rerun to resume. Exit 0 only if all succeed.

    Finished scenes are skipped, a scene killed half-way resumes from its checkpoints, a
    failed scene does not stop the others. Needs Ray: pip install 'pano4d[cluster]'."""
    from pano4d.batch import batch_table, run_batch

    result = run_batch(scenes, report, address, gpus_per_scene, cpus_per_scene, backend, console)
    table_console().print(batch_table(result))
    console.print(f"wrote {report}")
    if not result.ok:
        raise typer.Exit(code=1)


@app.command()
def demo(
    out: Annotated[Path, typer.Argument(help="Output folder.")] = Path("demo"),
    width: Annotated[int, typer.Option(help="Panorama width.")] = 1024,
    frames: Annotated[int, typer.Option(min=2, help="Number of frames.")] = 8,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    preset: Annotated[Literal["draft", "balanced", "max"], typer.Option()] = "draft",
) -> None:
    """The main job on the embedded defaults (no weights): synth → animate → train → previews."""
    from pano4d.train import demo as run_demo

    synth_height(width, None)
    metrics = run_demo(out, width=width, frames=frames, seed=seed, preset=preset)
    print_run_table(metrics, out / "output", "pano4d demo")


def print_run_table(metrics: dict[str, Any], output: Path, title: str) -> None:
    """How train and demo end: a few rows of metrics.json (pano4d.summary.run_table)."""
    from pano4d.summary import run_table

    table_console().print(run_table(metrics, output, title))


def table_console() -> Console:
    """The console a closing table is drawn on: into a file or a CI log it is drawn wide
    enough that paths and errors stay on one line."""
    return console if console.is_terminal else Console(stderr=True, width=160)


def main() -> None:
    try:
        app()
    except KeyboardInterrupt:
        console.print("interrupted")
        sys.exit(130)


if __name__ == "__main__":
    main()
