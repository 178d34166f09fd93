"""The frames as the animating phase stores them (pano4d.animate.frames): the static panorama
once and each frame's moving box. The box wraps round the seam, the stored frames equal the
whole frames computed the old way, the lifting phase's downsampled frames equal those of the
whole frames bit for bit, and the whole frames can be had as images again."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from pano4d import metrics
from pano4d.animate import pipeline
from pano4d.animate.flow import FlowAnimator
from pano4d.animate.frames import FrameBox, WholeFrames, area_resize, open_frames
from pano4d.animate.pipeline import enforce_static, run_animate
from pano4d.cli import app
from pano4d.config import SceneConfig, validate_config
from pano4d.images import read_image, read_panorama, write_image
from pano4d.regions import build_regions

WIDTH, HEIGHT = 512, 256


def across_the_seam(tmp_path: Path, frames: int = 3) -> SceneConfig:
    """A textured panorama with one region straddling u = W (the box must wrap)."""
    rng = np.random.default_rng(3)
    image = rng.random((HEIGHT // 8, WIDTH // 8, 3), dtype=np.float32)
    image = np.kron(image, np.ones((8, 8, 1), np.float32)) * 0.8 + 0.1
    write_image(tmp_path / "panorama.png", image, bits=16)
    return validate_config(
        {
            "panorama": "panorama.png",
            "regions": [{"box": [470, 100, 40, 160], "motion": {"speed": 3.0}}],
            "animate": {"frames": frames, "border_px": 4},
            "output": "out",
        },
        base_dir=tmp_path,
    )


def test_the_box_takes_the_short_way_round_the_seam() -> None:
    moving = torch.zeros(8, 20, dtype=torch.bool)
    moving[2:5, 17:] = True
    moving[3, :2] = True
    box = FrameBox.around(moving)
    assert (box.top, box.bottom, box.left, box.count) == (2, 5, 17, 5)
    image = np.arange(8 * 20 * 3, dtype=np.float32).reshape(8, 20, 3)
    crop = box.crop(image)
    assert crop.shape == (3, 5, 3)
    assert np.array_equal(crop[:, 3:], image[2:5, :2])
    assert np.array_equal(crop[:, :3], image[2:5, 17:])
    pasted = np.zeros_like(image)
    box.paste(pasted, crop)
    assert np.array_equal(pasted[2:5, 17:], image[2:5, 17:]) and pasted[:2].sum() == 0
    moving[6, 5:15] = True  # the widest gap is now columns 2–4
    assert FrameBox.around(moving) == FrameBox(20, 8, 2, 7, 5, 17)
    moving[0] = True  # no empty column: the whole width
    assert FrameBox.around(moving) == FrameBox(20, 8, 0, 7, 0, 20)
    assert FrameBox.from_json(box.to_json()) == box


def test_stored_frames_equal_the_whole_frames_computed_the_old_way(tmp_path: Path) -> None:
    """Static pixels are the input's bit for bit; moving pixels are those of the whole-frame
    computation (FlowAnimator.frame(t) over the whole image, the static pixels enforced,
    written as a whole 16-bit PNG and read back), bit for bit."""
    cfg = across_the_seam(tmp_path)
    result = run_animate(cfg, progress=False)
    box = result.store.box()
    assert box.left + box.count > WIDTH  # the stored box wraps round the seam
    assert box.count * (box.bottom - box.top) < WIDTH * HEIGHT // 4
    panorama = read_panorama(cfg.panorama)
    regions = build_regions(cfg, WIDTH, HEIGHT)
    animator = FlowAnimator(torch.from_numpy(panorama), regions, cfg.animate.frames, cfg.seed)
    still = regions.blend.numpy() == 0
    for t, frame in enumerate(result.store.frames()):
        whole = enforce_static(animator.frame(t), panorama, regions.blend.numpy())
        write_image(tmp_path / "whole.png", whole, bits=16)
        reference = read_image(tmp_path / "whole.png")
        assert np.array_equal(frame.view(np.uint32), reference.view(np.uint32)), t
        assert np.array_equal(frame[still].view(np.uint32), panorama[still].view(np.uint32)), t
    moved = frame[~still] - panorama[~still]
    assert float(np.abs(moved).mean()) > 0.01


@pytest.mark.parametrize("size", [(512, 256), (256, 128), (200, 100), (96, 48), (130, 65)])
def test_downsampled_frames_equal_those_of_the_whole_frames(
    tmp_path: Path, size: tuple[int, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the lifting phase reads: equal bit for bit to area-resizing each whole frame,
    for sizes whose area windows do and do not divide the panorama evenly."""
    monkeypatch.setattr(pipeline, "_write_video_and_measure", lambda *_: {})
    store = run_animate(across_the_seam(tmp_path), progress=False).store
    whole = torch.stack([area_resize(torch.from_numpy(f), size) for f in store.frames()])
    downsampled = store.area_downsampled(size)
    assert downsampled.shape == whole.shape and torch.equal(downsampled, whole)
    assert not torch.equal(downsampled[1], downsampled[0])  # the frames do move


def test_the_whole_frames_come_back_as_images(tmp_path: Path) -> None:
    """`pano4d animate --frames-out DIR` writes whole frames; they read back as the store's
    frames, and every reader (lifting, eval) takes either form alike."""
    cfg = across_the_seam(tmp_path)
    (tmp_path / "scene.yaml").write_text(
        "panorama: panorama.png\noutput: out\n"
        "regions:\n  - box: [470, 100, 40, 160]\n    motion: {speed: 3.0}\n"
        "animate: {frames: 3, border_px: 4}\n"
    )
    out = tmp_path / "whole"
    arguments = ["animate", str(tmp_path / "scene.yaml"), "--frames-out", str(out)]
    run = CliRunner().invoke(app, arguments)
    assert run.exit_code == 0, run.output
    store = pipeline.frame_store(cfg)
    exported = open_frames(out, 3, ".png")
    assert isinstance(exported, WholeFrames) and [p.name for p in exported.paths] == [
        "0000.png", "0001.png", "0002.png"
    ]  # fmt: skip
    for mine, theirs in zip(store.frames(), exported.frames(), strict=True):
        assert mine.shape == (HEIGHT, WIDTH, 3) and np.array_equal(mine, theirs)
    assert exported.size() == store.size() == (WIDTH, HEIGHT)
    assert torch.equal(exported.area_downsampled((200, 100)), store.area_downsampled((200, 100)))
    mask = build_regions(cfg, WIDTH, HEIGHT).mask.numpy()
    assert metrics.evaluate_frames(out, cfg.panorama, mask) == metrics.evaluate_frames(
        store.folder, cfg.panorama, mask
    )


def test_video_metrics_of_the_box_rows_are_those_of_the_whole_frames() -> None:
    """The animating phase measures only the rows of the box (the rest of every frame is
    the static panorama): the same figures as measuring the whole frames, the maxima and
    the flow bit for bit, the mean steps up to the order of a float sum. 1024 wide: the
    flow is measured at half resolution, and the rows (odd bounds) are not whole cells;
    the mask reaches beyond the rows, so the means over it must count what lies outside."""
    rng = np.random.default_rng(5)
    coarse = rng.random((64, 128, 3), dtype=np.float32)
    panorama = np.kron(coarse, np.ones((8, 8, 1), np.float32))
    mask = np.zeros((512, 1024), bool)
    mask[61:301, 300:700] = True
    top, bottom = 101, 203
    frames = []
    for t in range(4):
        frame = panorama.copy()
        frame[top:bottom, 320:680] = np.roll(panorama[top:bottom, 320:680], 3 * t, axis=1)
        frames.append(frame)
    whole, rows = metrics.VideoMetrics(panorama, mask), metrics.VideoMetrics(panorama, mask)
    for frame in frames:
        whole.add(frame)
        rows.add(frame, rows=(top, bottom))
    assert whole.flows == rows.flows and whole.flows[0][0] > 0.5
    assert whole.seams == rows.seams and whole.static_max == rows.static_max
    assert rows.steps_moving == pytest.approx(whole.steps_moving, rel=1e-5)
    assert min(whole.steps_moving) > 1e-3
    assert rows.result() == pytest.approx(whole.result(), rel=1e-5, abs=1e-9)


# --- the working-size store ------------------------------------------------------------------
def test_a_working_size_store_beside_the_full_resolution_one(tmp_path: Path) -> None:
    """`pano4d train` animates at the working size into a store of its own: frames of that
    size, bit-exact (EXR float), static pixels the input area-downsampled once; the
    full-resolution store of `pano4d animate` is another store, and neither run makes the
    other's stale; another size is a third store."""
    cfg = across_the_seam(tmp_path)
    size = (128, 64)
    small = run_animate(cfg, size, progress=False)
    assert small.folder == tmp_path / "out" / "animate" / "128x64"
    assert small.store.size() == size and small.store.static_path.suffix == ".exr"
    full = run_animate(cfg, progress=False)
    assert full.folder == tmp_path / "out" / "animate" and full.store.size() == (WIDTH, HEIGHT)
    assert run_animate(cfg, size, progress=False).skipped
    assert run_animate(cfg, progress=False).skipped
    assert run_animate(cfg, (WIDTH, HEIGHT), progress=False).skipped  # its own size: one store
    assert run_animate(cfg, (256, 128), progress=False).folder.name == "256x128"

    source = pipeline.animation_input(cfg, size)
    expected = area_resize(torch.from_numpy(read_panorama(cfg.panorama)), size).numpy()
    assert np.array_equal(source.panorama, expected)
    still = source.regions.blend.numpy() == 0
    frames = list(small.store.frames())
    assert all(f.shape == (64, 128, 3) for f in frames)
    for frame in frames:
        assert np.array_equal(frame[still].view(np.uint32), expected[still].view(np.uint32))
    render, _ = pipeline.frame_renderer(cfg, source, None)
    made = enforce_static(render(1), expected, source.regions.blend.numpy())
    assert np.array_equal(frames[1].view(np.uint32), made.view(np.uint32))  # stored exactly
    assert float(np.abs(frames[1] - frames[0]).mean()) > 1e-3


def test_working_size_frames_match_the_full_resolution_frames_downsampled(
    tmp_path: Path,
) -> None:
    """Against the full-resolution frames area-downsampled as `prepare` does: pixels one
    working pixel or more from the blend equal bit for bit, the moving region close."""
    cfg = across_the_seam(tmp_path)
    size = (256, 128)
    whole = run_animate(cfg, progress=False).store.area_downsampled(size)
    small = run_animate(cfg, size, progress=False).store.area_downsampled(size)
    blend = pipeline.animation_input(cfg, size).regions.blend
    near = torch.nn.functional.max_pool2d((blend > 0)[None, None].float(), 3, 1, 1)[0, 0] > 0
    far = ~near
    assert torch.equal(small[:, far], whole[:, far])
    moving = blend > 0
    for t in range(1, cfg.animate.frames):
        mse = float(((small[t][moving] - whole[t][moving]) ** 2).mean())
        assert -10 * np.log10(mse) > 25.0, t


def test_a_region_smaller_than_a_working_pixel_keeps_one(tmp_path: Path) -> None:
    """A box of a few input pixels at the north pole keeps a blend weight above 0 at the
    input's size (the distance field near a pole pools columns), and covers no working pixel
    by half: it is grown to its most-covered working pixel (the editor preview's rule) and
    animates; a box between pixel centres covers no input pixel and is refused with one line
    naming it."""
    from pano4d.regions import RegionError

    cfg = across_the_seam(tmp_path)
    tiny = cfg.regions[0].model_copy(update={"box": [100.0, 0.0, 103.0, 2.0]})
    cfg = cfg.model_copy(update={"regions": [tiny]})
    full = build_regions(cfg, WIDTH, HEIGHT)  # at the input's size every pixel moves too
    assert int(full.mask.sum()) == 6 and bool((full.blend[full.mask] > 0).all())
    source = pipeline.animation_input(cfg, (64, 32))
    assert int(source.regions.mask.sum()) == 1 and float(source.regions.blend.max()) > 0
    result = run_animate(cfg, (64, 32), progress=False)
    box = result.store.box()
    assert (box.top, box.count) == (0, 1)
    empty = tiny.model_copy(update={"box": [100.6, 10.6, 101.4, 11.4]})
    with pytest.raises(RegionError, match=r"regions\[0\] \(box\) covers no pixel of the 512×256"):
        pipeline.animation_input(cfg.model_copy(update={"regions": [empty]}), (64, 32))
