"""What a finished run's metrics.json (``lift.export.run_metrics``) says, as pano4d prints it.

``run_table`` is how ``pano4d train`` and ``pano4d demo`` end: the stage times, the Gaussian
counts, the novel-view quality where the scene has ground truth, and where the files are
(metrics.json holds everything else). ``summarise`` is what the batch table shows of each
scene; ``duration`` writes seconds as every table here shows them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich import box
from rich.table import Table
from rich.text import Text

# What a run leaves in its output folder for a person to open, in the order shown
# (lift.export writes them; densify.jsonl and losses.json beside them are for scripts).
RUN_FILES = ("scene.ply4d", "preview.mp4", "contact.png", "loss.png", "metrics.json")


def summarise(metrics: dict[str, Any]) -> dict[str, Any]:
    """The figures a table row shows of a run: seconds per stage, Gaussians stored, and
    PSNR per camera displacement of the ground-truth views (empty without them)."""
    return {
        "timings_s": metrics.get("timings_s", {}),
        "gaussians": metrics.get("gaussians", {}).get("stored"),
        "psnr": {k: v["psnr"] for k, v in _by_displacement(metrics).items()},
    }


def run_table(metrics: dict[str, Any], output: Path, title: str = "pano4d train") -> Table:
    """The end of a run in a few rows (see the module docstring)."""
    table = Table(title=f"{title}: done", box=box.SIMPLE_HEAD, show_header=False)
    table.add_column("what", style="bold")
    table.add_column("value", overflow="fold")
    timings: dict[str, float] = metrics.get("timings_s", {})
    stages = ", ".join(f"{name} {duration(s)}" for name, s in timings.items())
    table.add_row("time", f"{duration(sum(timings.values()))} ({stages})")
    counts = metrics.get("gaussians", {})
    dynamic = counts.get("dynamic", [])
    stored = f"{counts.get('stored', 0):,} stored: {counts.get('static', 0):,} static once, "
    if counts.get("dynamic_model", "per_timestamp") != "per_timestamp":  # one set for all
        stored += f"{sum(dynamic):,} dynamic once for all {counts['timestamps']} timestamps"
    else:
        per_time = f"{min(dynamic):,}" if dynamic else "0"
        if dynamic and max(dynamic) != min(dynamic):
            per_time += f"–{max(dynamic):,}"
        stored += f"{per_time} dynamic at each of {len(dynamic)} timestamps"
    table.add_row("Gaussians", stored)
    views = _by_displacement(metrics)
    quality = "; ".join(
        f"{v['psnr']:.1f} dB PSNR, SSIM {v['ssim']:.3f} with the camera moved {moved}"
        for moved, v in views.items()
    )
    table.add_row("novel views", quality or "no ground truth (gt/views.json) beside the panorama")
    if "training_fit" in metrics:
        table.add_row("limits", limits(metrics["training_fit"]))
    table.add_row("output", Text(str(output)))
    files = [name for name in RUN_FILES if (output / name).is_file()]
    table.add_row("files", Text(", ".join(files)))
    return table


def _by_displacement(metrics: dict[str, Any]) -> dict[str, dict[str, float]]:
    views = metrics.get("novel_views") or {}
    return dict(views.get("by_displacement") or {})


def limits(fit: dict[str, Any]) -> str:
    """What bounds the scene's quality (``lift.export.training_fit``), and so which lever
    would raise it: the Gaussians' fit to the working panorama, or the working panorama's
    resolution against the input's."""
    (ww, wh), (iw, ih) = fit["working_size"], fit["input_size"]
    text = f"the Gaussians fit the {ww}×{wh} working panorama to {fit['fit_psnr']:.1f} dB"
    more = "more Gaussians would help most (densify, init_stride, max_gaussians)"
    resolution = fit.get("resolution_psnr")
    if resolution is None:
        return f"{text} (the input's own size): {more}"
    finer = "a finer working panorama would help most (a larger view_size or preset)"
    lever = more if fit["fit_psnr"] < resolution else finer
    return f"{text}; it holds {resolution:.1f} dB of the {iw}×{ih} input: {lever}"


def duration(value: float | None) -> str:
    """Seconds as a table shows them: 4.2s, 3m07s, 1h05m; '-' for None."""
    if value is None:
        return "-"
    if value < 60:
        return f"{value:.1f}s"
    minutes, seconds = divmod(round(value), 60)
    return f"{minutes}m{seconds:02d}s" if minutes < 60 else f"{minutes // 60}h{minutes % 60:02d}m"
