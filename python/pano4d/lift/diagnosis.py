"""What each optimisation of a lifting run did, for the user (written beside metrics.json).

Every optimisation (the static set; the dynamic set of each timestamp) keeps a ``TrainLog``:
its loss and each active loss term every ``LOSS_EVERY`` steps, and one ``DensifyStats`` per
densify-and-prune. The log is part of the trainer's checkpoint, so a resumed run's log is the
uninterrupted run's. ``write_diagnosis`` writes

- ``densify.jsonl``: per optimisation a ``start`` line (its Gaussians), a ``densify`` line
  per densify-and-prune (pruned for opacity, split or cloned for their screen-space gradient
  and from which gradient on, clipped by the budget, and whether the gradient or the budget
  limited it) and an ``end`` line (what it stored, where it stopped and why), so that
  start + Σ (split + cloned − pruned − clipped) = end;
- ``losses.json``: the loss curves and each optimisation's stop (``convergence.Stop``);
- ``loss.png``: those curves, a panel for the static set and one for the dynamic sets (the
  timestamps one after another), one curve per active term, densification steps dotted, a
  stop before the preset's count marked with a short bar at the top.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, SupportsFloat

import numpy as np
import OpenImageIO as oiio

from pano4d.fsutil import write_json_atomic, write_text_atomic
from pano4d.images import write_image
from pano4d.lift.convergence import Stop

# Steps between loss records: ``pipeline.run_trainer`` records the loss terms this often,
# and the resident trainer reads its loss back from the device this often (and at the last
# step) so that each record holds that step's loss.
LOSS_EVERY = 10
# The terms a loss record may hold, in plot order, and their colours.
TERMS = {
    "total": (0.95, 0.95, 0.95),
    "l1": (0.35, 0.7, 1.0),
    "d_ssim": (0.3, 0.85, 0.4),
    "temporal": (1.0, 0.75, 0.2),
    "geo": (0.9, 0.35, 0.9),
    "sem": (1.0, 0.35, 0.3),
}
TERM_NAMES = {
    "total": "L (weighted sum)",
    "l1": "L1",
    "d_ssim": "1 - SSIM",
    "temporal": "L_temporal",
    "geo": "1 - Pearson (L_geo)",
    "sem": "L_sem",
}


@dataclass(frozen=True)
class DensifyStats:
    """One densify-and-prune: counts and the gradient the densified Gaussians reached."""

    step: int
    before: int  # Gaussians going in
    pruned: int  # dropped for opacity below PRUNE_OPACITY
    split: int  # large ones split in two (each parent is replaced by two children)
    cloned: int  # small ones copied (the original stays)
    clipped: int  # dropped afterwards to stay within the budget (the least opaque)
    after: int  # Gaussians coming out: before − pruned + split + cloned − clipped
    budget: int
    candidates: int  # surviving Gaussians whose mean gradient reached DENSIFY_GRADIENT
    seen: int  # surviving Gaussians some view gave a position gradient since the last one
    threshold: float | None  # smallest mean position gradient among the densified ones
    # What bounded the count densified: "gradient" (every candidate was: the scene's need)
    # or "budget" (no room for all of them; the largest gradients went first).
    limit: str


@dataclass
class TrainLog:
    """What one optimisation did: loss records and densify-and-prune statistics."""

    name: str  # "static" or "dynamic t=<t>"
    start: int  # Gaussians when it started
    losses: list[dict[str, float]] = field(default_factory=list)  # {"step", "view", term: …}
    densify: list[DensifyStats] = field(default_factory=list)
    stop: Stop | None = None  # where and why it stopped, once it has
    # What a step rendered (a dynamic step renders windows, lift.windows): the windows'
    # share of the views' pixels and how many of the static Gaussians it drew with the set.
    window_share: float = 1.0
    static_drawn: int = 0

    def record_loss(self, step: int, view: int, terms: Mapping[str, SupportsFloat]) -> None:
        """The loss terms of ``step``, whose one view was ``view``."""
        unknown = set(terms) - set(TERMS)
        if unknown:
            raise ValueError(f"unknown loss terms {sorted(unknown)}; known: {list(TERMS)}")
        record = {k: float(v) for k, v in terms.items()}
        self.losses.append({"step": float(step), "view": float(view), **record})

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "start": self.start,
            "losses": [dict(r) for r in self.losses],
            "densify": [asdict(d) for d in self.densify],
            "stop": self.stop.to_dict() if self.stop is not None else None,
            "window_share": self.window_share,
            "static_drawn": self.static_drawn,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainLog:
        stop = d.get("stop")  # absent in checkpoints written before the stop rule
        return cls(
            d["name"], int(d["start"]), [dict(r) for r in d["losses"]],
            [DensifyStats(**s) for s in d["densify"]],
            Stop(**stop) if stop is not None else None,
            float(d.get("window_share", 1.0)), int(d.get("static_drawn", 0)),
        )  # fmt: skip

    def terms(self) -> list[str]:
        """The terms recorded at least once, in TERMS order."""
        seen = {k for r in self.losses for k in r if k in TERMS}
        return [t for t in TERMS if t in seen]


def densify_lines(log: TrainLog, stored: int) -> list[dict[str, Any]]:
    """The densify.jsonl lines of one optimisation that stored ``stored`` Gaussians."""
    lines: list[dict[str, Any]] = [{"event": "start", "optimisation": log.name,
                                    "gaussians": log.start}]  # fmt: skip
    for d in log.densify:
        lines.append({"event": "densify", "optimisation": log.name, **asdict(d)})
    stop = log.stop.to_dict() if log.stop is not None else None
    lines.append({"event": "end", "optimisation": log.name, "gaussians": stored, "stop": stop})
    return lines


def write_diagnosis(out: Path, logs: list[tuple[TrainLog, int]]) -> None:
    """densify.jsonl, losses.json and loss.png in ``out`` for ``logs`` (each with the number
    of Gaussians its optimisation stored)."""
    lines = [json.dumps(line) for log, stored in logs for line in densify_lines(log, stored)]
    write_text_atomic(out / "densify.jsonl", "\n".join(lines) + "\n")
    write_json_atomic(out / "losses.json", {
        "every": LOSS_EVERY,
        "names": TERM_NAMES,
        "optimisations": [{"name": log.name, "terms": log.terms(), "losses": log.losses,
                           "stop": log.stop.to_dict() if log.stop is not None else None,
                           "window_share": log.window_share, "static_drawn": log.static_drawn}
                          for log, _ in logs],
    })  # fmt: skip
    static = [log for log, _ in logs if log.name == "static"]
    dynamic = [log for log, _ in logs if log.name != "static"]
    panels = [("static set", static)] if static else []
    if dynamic:
        panels.append(("dynamic sets, one timestamp after another", dynamic))
    plot_losses(out / "loss.png", panels)


# --- the plot ---------------------------------------------------------------------------------
PANEL_W, PANEL_H = 960, 320
MARGIN_L, MARGIN_R, MARGIN_T, MARGIN_B = 70, 20, 56, 36
FONT = 14
BACKGROUND = (0.08, 0.08, 0.09)
STOP = (0.4, 1.0, 0.6)  # the mark of an optimisation the stop rule ended early


def plot_losses(path: Path, panels: list[tuple[str, list[TrainLog]]]) -> list[list[str]]:
    """Draw each panel (a title and the logs it shows, one after another along x) with a
    log-scaled y axis; returns the terms drawn per panel (one curve each)."""
    height = PANEL_H * max(1, len(panels))
    buf = oiio.ImageBuf(oiio.ImageSpec(PANEL_W, height, 3, "float"))
    oiio.ImageBufAlgo.fill(buf, list(BACKGROUND))
    drawn = []
    for index, (title, logs) in enumerate(panels):
        drawn.append(_panel(buf, index * PANEL_H, title, logs))
    pixels = buf.get_pixels(oiio.FLOAT).reshape(height, PANEL_W, 3)
    write_image(path, np.ascontiguousarray(pixels))
    return drawn


def _panel(buf: oiio.ImageBuf, top: int, title: str, logs: list[TrainLog]) -> list[str]:
    x0, x1 = MARGIN_L, PANEL_W - MARGIN_R
    y0, y1 = top + MARGIN_T, top + PANEL_H - MARGIN_B
    grey, faint = (0.6, 0.6, 0.6), (0.25, 0.25, 0.28)
    # One x axis for the panel: each log's steps shifted past the previous log's.
    offsets, total = [], 0.0
    for log in logs:
        offsets.append(total)
        total += max((r["step"] for r in log.losses), default=0.0)
    values = [v for log in logs for r in log.losses for k, v in r.items()
              if k in TERMS and v > 0 and math.isfinite(v)]  # fmt: skip
    start = sum(log.start for log in logs[:1])
    _text(buf, x0, top + FONT + 6, f"{title} ({start} Gaussians at the start)", grey)
    if not values or total <= 0:
        _text(buf, x0, (y0 + y1) // 2, "no optimisation steps", grey)
        return []
    lo = math.floor(math.log10(min(values)))
    hi = math.ceil(math.log10(max(values)))
    hi = max(hi, lo + 1)

    def to_x(step: float) -> int:
        return round(x0 + (x1 - x0) * step / total)

    def to_y(value: float) -> int:
        v = math.log10(max(value, 10.0**lo))
        return round(y1 - (y1 - y0) * (v - lo) / (hi - lo))

    for decade in range(lo, hi + 1):
        y = to_y(10.0**decade)
        oiio.ImageBufAlgo.render_line(buf, x0, y, x1, y, list(faint))
        _text(buf, 6, y + FONT // 2 - 2, f"1e{decade}", grey)
    for tick in range(5):
        step = total * tick / 4
        _text(buf, to_x(step) - 10, y1 + FONT + 8, f"{step:.0f}", grey)
    for log, offset in zip(logs, offsets, strict=True):
        if offset > 0:  # where the next timestamp starts
            x = to_x(offset)
            oiio.ImageBufAlgo.render_line(buf, x, y0, x, y1, list(grey))
        for d in log.densify:  # densification steps, dotted
            x = to_x(offset + d.step)
            for y in range(y0, y1, 6):
                oiio.ImageBufAlgo.render_point(buf, x, y, list(grey))
        if log.stop is not None and log.stop.reason != "count":  # stopped early: a bar
            x = to_x(offset + log.stop.step)
            oiio.ImageBufAlgo.render_box(buf, x - 1, y0, x + 1, y0 + 12, list(STOP), fill=True)
    oiio.ImageBufAlgo.render_box(buf, x0, y0, x1, y1, list(grey))
    terms = [t for t in TERMS if any(t in log.terms() for log in logs)]
    for term in terms:
        colour = list(TERMS[term])
        for log, offset in zip(logs, offsets, strict=True):
            points = [(to_x(offset + r["step"]), to_y(r[term])) for r in log.losses if term in r]
            for (xa, ya), (xb, yb) in itertools.pairwise(points):
                oiio.ImageBufAlgo.render_line(buf, xa, ya, xb, yb, colour)
    legend_x = x0
    for term in terms:  # the legend, under the title, in each curve's colour
        label = TERM_NAMES[term]
        _text(buf, legend_x, top + 2 * FONT + 12, label, TERMS[term])
        legend_x += oiio.ImageBufAlgo.text_size(label, FONT).width + 18
    return terms


def _text(buf: oiio.ImageBuf, x: int, y: int, text: str, colour: tuple[float, ...]) -> None:
    if not oiio.ImageBufAlgo.render_text(buf, x, y, text, FONT, "", list(colour)):
        raise RuntimeError(f"cannot draw {text!r} on the loss plot: {buf.geterror()}")
