"""The per-run diagnosis (pano4d.lift.diagnosis): the densification log adds up, the loss
plot draws one curve per active term, and `pano4d train` writes both beside metrics.json."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from pano4d.images import read_image
from pano4d.lift.diagnosis import (
    MARGIN_B,
    MARGIN_L,
    MARGIN_R,
    MARGIN_T,
    PANEL_H,
    PANEL_W,
    TERMS,
    DensifyStats,
    TrainLog,
    plot_losses,
    write_diagnosis,
)


def _log(name: str, start: int, steps: int, terms: list[str]) -> TrainLog:
    log = TrainLog(name, start)
    for step in range(0, steps + 1, 10):
        log.record_loss(step, {t: 0.5 * math.exp(-step / 300) + 0.01 * (i + 1)
                               for i, t in enumerate(terms)})  # fmt: skip
    return log


def test_a_log_survives_its_checkpoint_form() -> None:
    log = _log("static", 100, 50, ["total", "l1", "geo"])
    log.densify.append(DensifyStats(20, 100, 3, 10, 0, 107, 1000, 90, 0.02, "share"))
    again = TrainLog.from_dict(json.loads(json.dumps(log.to_dict())))
    assert again == log
    assert again.terms() == ["total", "l1", "geo"]
    with pytest.raises(ValueError, match="unknown loss terms"):
        log.record_loss(60, {"l2": 1.0})


def test_the_plot_draws_one_curve_per_active_term(tmp_path: Path) -> None:
    terms = ["total", "l1", "d_ssim", "geo"]
    static = _log("static", 100, 200, terms)
    dynamic = [
        _log("dynamic t=0", 40, 200, terms),
        _log("dynamic t=1", 40, 100, [*terms, "temporal"]),
    ]
    path = tmp_path / "loss.png"
    drawn = plot_losses(path, [("static", [static]), ("dynamic", dynamic)])
    assert drawn == [["total", "l1", "d_ssim", "geo"], ["total", "l1", "d_ssim", "temporal", "geo"]]
    image = read_image(path)
    assert image.shape == (640, 960, 3)
    # Inside each panel's axes (below the legend) every drawn term's colour is on the plot
    # and an absent term's is not.
    for panel, terms in enumerate(drawn):
        top = panel * PANEL_H
        axes = image[top + MARGIN_T : top + PANEL_H - MARGIN_B, MARGIN_L : PANEL_W - MARGIN_R]
        pixels = axes.reshape(-1, 3)
        for term in TERMS:
            close = np.abs(pixels - np.array(TERMS[term])).max(-1) < 0.02
            assert (int(close.sum()) > 50) == (term in terms), (panel, term)


def test_the_densify_log_adds_up(tmp_path: Path) -> None:
    log = _log("static", 1000, 30, ["total"])
    log.densify += [
        DensifyStats(10, 1000, 20, 100, 0, 1080, 1100, 900, 0.01, "share"),
        DensifyStats(20, 1080, 5, 60, 35, 1100, 1100, 1000, 0.02, "budget"),
    ]
    write_diagnosis(tmp_path, [(log, 1100)])
    lines = [json.loads(line) for line in (tmp_path / "densify.jsonl").read_text().splitlines()]
    assert [line["event"] for line in lines] == ["start", "densify", "densify", "end"]
    count = lines[0]["gaussians"]
    for line in lines[1:-1]:
        assert line["before"] == count
        count = count - line["pruned"] + line["split"] - line["clipped"]
        assert line["after"] == count
    assert count == lines[-1]["gaussians"] == 1100
    losses = json.loads((tmp_path / "losses.json").read_text())
    assert losses["optimisations"][0]["terms"] == ["total"]
