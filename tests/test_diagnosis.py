"""The per-run diagnosis (pano4d.lift.diagnosis): the densification log adds up, the loss
plot draws one curve per active term, and `pano4d train` writes both beside metrics.json (a
resumed run the uninterrupted run's)."""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from pano4d import synth
from pano4d.config import SceneConfig, load_config
from pano4d.images import read_image
from pano4d.lift.convergence import Stop
from pano4d.lift.diagnosis import (
    LOSS_EVERY,
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
from pano4d.train import run_train


def _log(name: str, start: int, steps: int, terms: list[str]) -> TrainLog:
    log = TrainLog(name, start)
    for step in range(0, steps + 1, 10):
        log.record_loss(step, step % 7, {t: 0.5 * math.exp(-step / 300) + 0.01 * (i + 1)
                                         for i, t in enumerate(terms)})  # fmt: skip
    return log


def test_a_log_survives_its_checkpoint_form() -> None:
    log = _log("static", 100, 50, ["total", "l1", "geo"])
    log.densify.append(DensifyStats(20, 100, 3, 6, 4, 0, 107, 1000, 10, 90, 0.02, "gradient"))
    log.stop = Stop(50, "converged", 0.004)
    again = TrainLog.from_dict(json.loads(json.dumps(log.to_dict())))
    assert again == log
    assert again.terms() == ["total", "l1", "geo"]
    with pytest.raises(ValueError, match="unknown loss terms"):
        log.record_loss(60, 0, {"l2": 1.0})


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
        DensifyStats(10, 1000, 20, 60, 40, 0, 1080, 1100, 100, 900, 0.01, "gradient"),
        DensifyStats(20, 1080, 5, 40, 20, 35, 1100, 1100, 90, 1000, 0.02, "budget"),
    ]
    write_diagnosis(tmp_path, [(log, 1100)])
    lines = [json.loads(line) for line in (tmp_path / "densify.jsonl").read_text().splitlines()]
    assert [line["event"] for line in lines] == ["start", "densify", "densify", "end"]
    count = lines[0]["gaussians"]
    for line in lines[1:-1]:
        assert line["before"] == count
        count = count - line["pruned"] + line["split"] + line["cloned"] - line["clipped"]
        assert line["after"] == count
    assert count == lines[-1]["gaussians"] == 1100
    losses = json.loads((tmp_path / "losses.json").read_text())
    assert losses["optimisations"][0]["terms"] == ["total"]


# --- what a training run writes -----------------------------------------------------------------
DENSIFYING = {
    "view_size": 16,
    "init_stride": 2,
    "align_iterations": 20,
    "gaussian_iterations": 40,  # densify-and-prune from step 8 to 20 (20 % to 50 %)
    "max_gaussians": 5000,
    "densify": True,
    "later_iteration_share": 0.25,  # 10 steps at t > 0
}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("scene")
    synth.write_scene(root, synth.make_scene(0, 128, 64, 3, views=4, view_size=24))
    return root


def _config(scene_dir: Path, output: Path) -> SceneConfig:
    """The scene at tiny densifying knobs, exact depth; the true frames as the animation."""
    shutil.copytree(scene_dir / "gt" / "frames", output / "animate" / "frames")
    cfg = load_config(scene_dir / "scene.yaml")
    depth = cfg.depth.model_copy(update={"backend": "file", "path": scene_dir / "depth.exr"})
    return cfg.model_copy(update={"overrides": DENSIFYING, "output": output, "depth": depth})


def _diagnosis(out: Path) -> tuple[list[dict], dict]:
    lines = [json.loads(line) for line in (out / "densify.jsonl").read_text().splitlines()]
    return lines, json.loads((out / "losses.json").read_text())


@pytest.mark.usefixtures("one_torch_thread")
def test_a_run_writes_its_diagnosis_beside_metrics_json(scene_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    metrics = run_train(_config(scene_dir, out), progress=False, render_backend="torch")
    lines, losses = _diagnosis(out)
    names = ["static", "dynamic t=0", "dynamic t=1", "dynamic t=2"]
    stored = [metrics["gaussians"]["static"], *metrics["gaussians"]["dynamic"]]
    # Per optimisation: a start line, its densify-and-prunes, an end line with what it stored;
    # the counts add up from one to the next, and every timestamp starts from t − 1's result.
    for name, count in zip(names, stored, strict=True):
        own = [line for line in lines if line["optimisation"] == name]
        steps = [line["step"] for line in own[1:-1]]
        assert [line["event"] for line in own] == ["start"] + ["densify"] * len(steps) + ["end"]
        if name == "static":  # one pass over the 20 views between two densify-and-prunes
            assert steps == [20]
        elif name == "dynamic t=0":  # every max(10, views seeing motion) steps in 8…20
            assert steps and steps[0] >= 10, steps
            assert steps == list(range(steps[0], 21, steps[0])), steps
        else:  # warm-started from t − 1's densified set: no growth again
            assert steps == []
        gaussians = own[0]["gaussians"]
        for line in own[1:-1]:
            assert line["before"] == gaussians
            assert line["split"] + line["cloned"] > 0 and line["limit"] == "gradient"
            gaussians = (
                line["before"] - line["pruned"] + line["split"] + line["cloned"] - line["clipped"]
            )
            assert line["after"] == gaussians
        assert own[-1]["gaussians"] == gaussians == count, name
    starts = {line["optimisation"]: line["gaussians"] for line in lines if line["event"] == "start"}
    assert starts["dynamic t=1"] == stored[1] and starts["dynamic t=2"] == stored[2]
    # Loss terms every LOSS_EVERY steps and at the last, L_temporal only once there is a t − 1.
    assert [o["name"] for o in losses["optimisations"]] == names
    # What a step rendered: the static stage whole views alone, a dynamic step its windows
    # (lift/windows.py) with part of the static set.
    static_log = losses["optimisations"][0]
    assert (static_log["window_share"], static_log["static_drawn"]) == (1.0, 0)
    for o in losses["optimisations"][1:]:
        assert 0 < o["window_share"] <= 1 and 0 < o["static_drawn"] <= stored[0], o["name"]
    for o in losses["optimisations"]:  # a later timestamp runs its share of the steps
        last = 40 if o["name"] in names[:2] else 10
        assert [r["step"] for r in o["losses"]] == list(range(LOSS_EVERY, last + 1, LOSS_EVERY))
        assert o["stop"]["step"] == last, o["name"]
        temporal = ["temporal"] if o["name"] in names[2:] else []
        assert o["terms"] == ["total", "l1", "d_ssim", *temporal, "geo"]
        for r in o["losses"]:  # the total is the weighted sum of the terms
            knobs = metrics["knobs"]
            # L_geo counts only over more than 16 weighted pixels the render covers: a step
            # on a 16-pixel view the moving region masks whole has none (which views come
            # up after a densify-and-prune depends on the run's random draws).
            weighted = 0.8 * r["l1"] + 0.2 * r["d_ssim"] + knobs["lambda_geo"] * r.get("geo", 0.0)
            weighted += knobs["lambda_temporal"] * r.get("temporal", 0.0)
            assert r["total"] == pytest.approx(weighted, rel=1e-5)
    assert read_image(out / "loss.png").shape == (2 * PANEL_H, PANEL_W, 3)


@pytest.mark.usefixtures("one_torch_thread")
def test_a_resumed_run_writes_the_uninterrupted_runs_diagnosis(
    scene_dir: Path, tmp_path: Path, interrupt_train: Callable
) -> None:
    run_train(_config(scene_dir, tmp_path / "a"), progress=False, render_backend="torch")
    cfg = _config(scene_dir, tmp_path / "b")
    # After a densify-and-prune, between checkpoints (every 4 steps).
    interrupt_train(cfg, [("static", 27), ("dynamic", 33)])
    run_train(cfg, progress=False, render_backend="torch", checkpoint_every=4)
    a, b = _diagnosis(tmp_path / "a"), _diagnosis(tmp_path / "b")
    assert a[0] == b[0]
    for run_a, run_b in zip(a[1]["optimisations"], b[1]["optimisations"], strict=True):
        assert run_a["name"] == run_b["name"] and run_a["terms"] == run_b["terms"]
        steps = [[r["step"] for r in run["losses"]] for run in (run_a, run_b)]
        assert steps[0] == steps[1]
        for ra, rb in zip(run_a["losses"], run_b["losses"], strict=True):
            assert ra == pytest.approx(rb, rel=1e-4), run_a["name"]
