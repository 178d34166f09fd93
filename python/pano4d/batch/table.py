"""The table ``pano4d batch`` ends with: a row per scene (``batch_table``)."""

from __future__ import annotations

from rich import box
from rich.table import Table
from rich.text import Text

from pano4d.batch.driver import BatchReport
from pano4d.lift.checkpoints import STAGES as LIFT_STAGES  # the lifting phase, in metrics.json
from pano4d.summary import duration


def batch_table(report: BatchReport) -> Table:
    """Every scene: status, seconds per phase (from its metrics.json), the task's wall time,
    Gaussians stored, PSNR of the ground-truth views, and the error of a failed scene."""
    table = Table(
        title=f"pano4d batch: {_count(len(report.scenes), 'scene')} in {duration(report.wall_s)}",
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
    )
    table.add_column("scene", overflow="fold")
    table.add_column("status")
    for name in ("animate", "lift", "export", "task", "Gaussians", "PSNR 1/5%"):
        table.add_column(name, justify="right")
    table.add_column("note", overflow="fold", min_width=24)
    colours = {"ok": "green", "resumed": "green", "skipped": "cyan", "failed": "red"}
    for s in report.scenes:
        t = s.timings_s
        lift = sum(t[k] for k in LIFT_STAGES if k in t) if t else None
        note = s.error or (f"from {s.resumed_from}" if s.resumed_from else "")
        if s.status == "skipped":
            note = "finished before"
        psnr = "/".join(f"{s.psnr[k]:.1f}" for k in ("1%", "5%") if k in s.psnr) or "-"
        table.add_row(
            Text(s.name),
            f"[{colours.get(s.status, 'yellow')}]{s.status}[/]",
            duration(t.get("animate")),
            duration(lift),
            duration(t.get("export")),
            duration(s.wall_s),
            f"{s.gaussians:,}" if s.gaussians is not None else "-",
            psnr,
            Text(note),
        )
    return table


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")
