"""Image, depth, mask and video files: exact round trips and a clear error for each bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pano4d import images
from pano4d.images import (
    ImageError,
    read_depth,
    read_image,
    read_mask,
    read_panorama,
    write_contact_sheet,
    write_image,
    write_video,
)

DATA = Path(__file__).parents[1] / ".." / "shared" / "data"
LAKE = DATA / "pano_lake.jpg"


def ramp(height: int, width: int, channels: int, levels: int, seed: int = 0) -> np.ndarray:
    """Random image whose values are exactly k / levels."""
    rng = np.random.default_rng(seed)
    steps = rng.integers(0, levels + 1, size=(height, width, channels))
    return steps.astype(np.float32) / np.float32(levels)


def no_temp_files(folder: Path) -> bool:
    return not any(".tmp" in p.name for p in folder.iterdir())


# --- round trips ------------------------------------------------------------------------
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_png_8bit_round_trip_is_exact(tmp_path: Path, channels: int) -> None:
    image = ramp(37, 53, channels, 255)
    write_image(tmp_path / "a.png", image)
    back = read_image(tmp_path / "a.png")
    assert back.dtype == np.float32
    assert back.shape == (37, 53, channels)
    np.testing.assert_array_equal(back, image)


def test_png_16bit_round_trip_is_exact(tmp_path: Path) -> None:
    image = ramp(64, 96, 3, 65535)
    write_image(tmp_path / "a.png", image, bits=16)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), image)


def test_png_quantises_by_rounding_and_clips(tmp_path: Path) -> None:
    image = np.array([[[-0.5], [0.2], [1.7], [0.51 / 255], [0.49 / 255]]], np.float32)
    write_image(tmp_path / "a.png", image)
    back = read_image(tmp_path / "a.png")[0, :, 0] * 255
    np.testing.assert_allclose(back, [0, 51, 255, 1, 0], atol=1e-4)


def test_exr_float_round_trip_is_exact_and_half_when_asked(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    image = (rng.standard_normal((20, 30, 3)) * 50).astype(np.float32)
    write_image(tmp_path / "f.exr", image)
    np.testing.assert_array_equal(read_image(tmp_path / "f.exr"), image)
    halves = image.astype(np.float16).astype(np.float32)
    write_image(tmp_path / "h.exr", image, bits=16)
    np.testing.assert_array_equal(read_image(tmp_path / "h.exr"), halves)
    assert (tmp_path / "h.exr").stat().st_size < (tmp_path / "f.exr").stat().st_size


def test_exr_rgba_keeps_colour_and_alpha_as_given(tmp_path: Path) -> None:
    image = ramp(8, 8, 4, 7)
    write_image(tmp_path / "a.exr", image)
    np.testing.assert_array_equal(read_image(tmp_path / "a.exr"), image)


def test_grey_2d_input_is_one_channel(tmp_path: Path) -> None:
    image = ramp(10, 20, 1, 255)[:, :, 0]
    write_image(tmp_path / "g.exr", image)
    assert read_image(tmp_path / "g.exr").shape == (10, 20, 1)


def test_jpeg_round_trip_is_close(tmp_path: Path) -> None:
    yy, xx = np.mgrid[0:64, 0:128].astype(np.float32)
    image = np.stack([xx / 127, yy / 63, 0.5 + 0 * xx], axis=2)
    write_image(tmp_path / "a.jpg", image)
    back = read_image(tmp_path / "a.jpg")
    assert back.shape == image.shape
    assert np.abs(back - image).mean() < 0.01


def test_real_panorama_reads_as_full_resolution_rgb() -> None:
    image = read_image(LAKE)
    assert image.shape == (2048, 4096, 3)
    assert image.dtype == np.float32
    assert image.min() >= 0.0 and image.max() <= 1.0
    assert image.std() > 0.05  # a photograph, not a blank
    # File values, no colour conversion: every value is a multiple of 1/255.
    steps = image[::97, ::89] * 255
    np.testing.assert_allclose(steps, steps.round(), atol=1e-4)
    panorama = read_panorama(LAKE)
    np.testing.assert_array_equal(panorama, image)


# --- writer checks ----------------------------------------------------------------------
def test_write_rejects_bad_requests(tmp_path: Path) -> None:
    image = np.zeros((4, 4, 3), np.float32)
    with pytest.raises(ImageError, match=r"cannot write '\.tif' files; use one of"):
        write_image(tmp_path / "a.tif", image)
    with pytest.raises(ImageError, match=r"\.png files take bits in \(8, 16\), got 12"):
        write_image(tmp_path / "a.png", image, bits=12)
    with pytest.raises(ImageError, match=r"\.jpg files take bits in \(8,\), got 16"):
        write_image(tmp_path / "a.jpg", image, bits=16)
    with pytest.raises(ImageError, match="JPEG stores 1 or 3 channels, got 4"):
        write_image(tmp_path / "a.jpg", np.zeros((4, 4, 4), np.float32))
    with pytest.raises(ImageError, match="expected float image data in \\[0, 1\\], got uint8"):
        write_image(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))
    nan = image.copy()
    nan[2, 1, 0] = np.nan
    with pytest.raises(ImageError, match=r"1 NaN/Inf values \(first at row 2, column 1"):
        write_image(tmp_path / "a.png", nan)
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_the_old_file(tmp_path: Path) -> None:
    target = tmp_path / "a.png"
    write_image(target, np.ones((4, 4, 3), np.float32))
    before = target.read_bytes()
    bad = np.ones((4, 4, 3), np.float32)
    bad[0, 0, 0] = np.inf
    with pytest.raises(ImageError):
        write_image(target, bad)
    assert target.read_bytes() == before
    assert no_temp_files(tmp_path)


# --- corrupt and missing files ----------------------------------------------------------
def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(ImageError, match="image file not found"):
        read_image(tmp_path / "nope.png")
    with pytest.raises(ImageError, match="found a directory"):
        read_image(tmp_path)


def test_garbage_is_unreadable(tmp_path: Path) -> None:
    path = tmp_path / "junk.png"
    path.write_bytes(b"this is not an image" * 20)
    with pytest.raises(ImageError, match="cannot read this image"):
        read_image(path)


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".exr"])
@pytest.mark.parametrize("keep", [0.3, 0.9, 0.995])
def test_truncated_files_are_reported(tmp_path: Path, suffix: str, keep: float) -> None:
    source = tmp_path / f"whole{suffix}"
    write_image(source, ramp(128, 256, 3, 255, seed=2))
    data = source.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ImageError, match=r"corrupt or truncated|cannot read this image"):
        read_image(cut)


def test_png_missing_only_its_end_chunk_is_truncated(tmp_path: Path) -> None:
    # libpng decodes every pixel without the final IEND chunk and reports nothing.
    source = tmp_path / "whole.png"
    write_image(source, ramp(32, 64, 3, 255))
    cut = tmp_path / "cut.png"
    cut.write_bytes(source.read_bytes()[:-12])
    with pytest.raises(ImageError, match="truncated PNG"):
        read_image(cut)


def test_truncated_real_jpeg_is_reported(tmp_path: Path) -> None:
    cut = tmp_path / "lake.jpg"
    data = LAKE.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageError, match="Premature end of JPEG file"):
        read_image(cut)


def test_corrupt_jpeg_body_is_reported(tmp_path: Path) -> None:
    source = tmp_path / "whole.jpg"
    write_image(source, ramp(128, 256, 3, 255, seed=3))
    data = bytearray(source.read_bytes())
    start = data.index(b"\xff\xda")  # start of scan: the entropy-coded pixels follow
    data[start + 40 : start + 400] = b"\xff\xd9" * 180
    (tmp_path / "bad.jpg").write_bytes(bytes(data))
    with pytest.raises(ImageError, match="corrupt or truncated"):
        read_image(tmp_path / "bad.jpg")


# --- panoramas --------------------------------------------------------------------------
def test_three_by_two_panorama_suggests_exact_sizes(tmp_path: Path) -> None:
    write_image(tmp_path / "p.png", np.zeros((512, 768, 3), np.float32))
    with pytest.raises(ImageError) as info:
        read_panorama(tmp_path / "p.png")
    message = str(info.value)
    assert "panorama is 768×512" in message
    assert "must be exactly 2:1" in message
    assert "pad it left and right to 1024×512 or crop its height to 768×384" in message


def test_too_wide_panorama_suggests_exact_sizes(tmp_path: Path) -> None:
    write_image(tmp_path / "p.png", np.zeros((300, 1001, 3), np.float32))
    with pytest.raises(
        ImageError, match="pad it top and bottom to 1002×501 or crop its width to 600×300"
    ):
        read_panorama(tmp_path / "p.png")


def test_small_panorama_is_rejected(tmp_path: Path) -> None:
    write_image(tmp_path / "p.png", np.zeros((128, 256, 3), np.float32))
    with pytest.raises(ImageError, match="panorama is 256×128, smaller than the minimum 512×256"):
        read_panorama(tmp_path / "p.png")


def test_panorama_channels_become_rgb(tmp_path: Path) -> None:
    grey = ramp(256, 512, 1, 255)
    write_image(tmp_path / "grey.png", grey)
    rgb = read_panorama(tmp_path / "grey.png")
    assert rgb.shape == (256, 512, 3)
    np.testing.assert_array_equal(rgb, np.repeat(grey, 3, axis=2))
    rgba = ramp(256, 512, 4, 255)
    write_image(tmp_path / "rgba.png", rgba)
    np.testing.assert_array_equal(read_panorama(tmp_path / "rgba.png"), rgba[:, :, :3])


def test_hdr_and_nan_panoramas_are_rejected(tmp_path: Path) -> None:
    hdr = np.full((256, 512, 3), 0.5, np.float32)
    hdr[3, 4, 1] = 7.0
    write_image(tmp_path / "hdr.exr", hdr)
    with pytest.raises(ImageError, match=r"values span \[0.5, 7\], expected \[0, 1\]; tone-map"):
        read_panorama(tmp_path / "hdr.exr")
    hdr[3, 4, 1] = np.nan
    write_image(tmp_path / "nan.exr", hdr)
    with pytest.raises(
        ImageError, match=r"panorama has 1 NaN/Inf values \(first at row 3, column 4"
    ):
        read_panorama(tmp_path / "nan.exr")


# --- depth ------------------------------------------------------------------------------
def test_exr_depth_reads_one_channel(tmp_path: Path) -> None:
    depth = np.random.default_rng(4).uniform(0.5, 900.0, (64, 128)).astype(np.float32)
    write_image(tmp_path / "d.exr", depth)
    back = read_depth(tmp_path / "d.exr")
    assert back.shape == (64, 128)
    np.testing.assert_array_equal(back, depth)


def test_nan_exr_depth_gives_count_and_location(tmp_path: Path) -> None:
    depth = np.ones((64, 128), np.float32)
    depth[10, 20] = np.nan
    depth[30, 5] = np.inf
    depth[40, 7] = np.nan
    write_image(tmp_path / "d.exr", depth)
    with pytest.raises(
        ImageError, match=r"depth has 3 NaN/Inf values \(first at row 10, column 20"
    ):
        read_depth(tmp_path / "d.exr")


def test_depth_must_be_positive_and_one_channel(tmp_path: Path) -> None:
    depth = np.ones((8, 16), np.float32)
    depth[2, 3] = 0.0
    write_image(tmp_path / "zero.exr", depth)
    with pytest.raises(ImageError, match=r"1 depth values are ≤ 0 \(first at row 2, column 3"):
        read_depth(tmp_path / "zero.exr")
    write_image(tmp_path / "rgb.exr", np.ones((8, 16, 3), np.float32))
    with pytest.raises(ImageError, match="a depth map has one channel, this file has 3"):
        read_depth(tmp_path / "rgb.exr")


def test_png_depth_is_16_bit_millimetres(tmp_path: Path) -> None:
    millimetres = np.array([[1, 1600, 65535]], np.float32)
    write_image(tmp_path / "d.png", millimetres[:, :, None] / 65535, bits=16)
    np.testing.assert_allclose(read_depth(tmp_path / "d.png"), [[0.001, 1.6, 65.535]], rtol=1e-6)
    write_image(tmp_path / "d8.png", np.ones((4, 4), np.float32))
    with pytest.raises(ImageError, match="must be 16-bit, this one is 8-bit"):
        read_depth(tmp_path / "d8.png")


# --- masks ------------------------------------------------------------------------------
def test_mask_same_size_and_nearest_resize(tmp_path: Path) -> None:
    small = np.zeros((4, 8), np.float32)
    small[1, 2] = 1.0
    small[3, 7] = 0.8
    write_image(tmp_path / "m.png", small)
    same = read_mask(tmp_path / "m.png", 8, 4)
    assert same.dtype == bool
    np.testing.assert_array_equal(same, small > 0.5)
    big = read_mask(tmp_path / "m.png", 32, 16)
    expected = np.kron(small > 0.5, np.ones((4, 4), bool))
    np.testing.assert_array_equal(big, expected)


def test_colour_mask_uses_mean_of_colours(tmp_path: Path) -> None:
    mask = np.zeros((4, 8, 4), np.float32)
    mask[0, 0, :3] = 1.0  # white
    mask[0, 1, 0] = 1.0  # pure red: mean 1/3, not white
    mask[..., 3] = 1.0
    write_image(tmp_path / "m.png", mask)
    got = read_mask(tmp_path / "m.png", 8, 4)
    assert got[0, 0] and not got[0, 1] and got.sum() == 1


def test_mask_with_other_aspect_is_an_error(tmp_path: Path) -> None:
    write_image(tmp_path / "m.png", np.zeros((30, 40), np.float32))
    with pytest.raises(ImageError, match="mask is 40×30, expected 512×256"):
        read_mask(tmp_path / "m.png", 512, 256)


# --- video and contact sheet ------------------------------------------------------------
def ffprobe(path: Path) -> dict:
    result = subprocess.run(
        ["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0",
         "-show_entries", "stream=codec_name,width,height,nb_read_frames,pix_fmt,r_frame_rate",
         "-of", "json", str(path)],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    return json.loads(result.stdout)["streams"][0]


def test_write_video_makes_h264_with_every_frame(tmp_path: Path) -> None:
    frames = (np.full((48, 96, 3), t / 12, np.float32) for t in range(12))
    assert write_video(tmp_path / "v.mp4", frames, fps=7) == 12
    info = ffprobe(tmp_path / "v.mp4")
    assert info["codec_name"] == "h264"
    assert (info["width"], info["height"]) == (96, 48)
    assert int(info["nb_read_frames"]) == 12
    assert info["r_frame_rate"] == "7/1"
    assert no_temp_files(tmp_path)


def test_write_video_pads_odd_sizes_and_takes_uint8(tmp_path: Path) -> None:
    frames = [np.full((31, 45, 3), 200, np.uint8)] * 3
    write_video(tmp_path / "v.mp4", frames, fps=24)
    info = ffprobe(tmp_path / "v.mp4")
    assert (info["width"], info["height"], int(info["nb_read_frames"])) == (46, 32, 3)


def test_write_video_errors_leave_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "v.mp4"
    mixed = [np.zeros((16, 16, 3), np.float32), np.zeros((16, 18, 3), np.float32)]
    with pytest.raises(ImageError, match=r"frame 1 has shape \(16, 18, 3\), the first frame"):
        write_video(target, mixed, fps=7)
    with pytest.raises(ImageError, match="no frames to write"):
        write_video(target, [], fps=7)
    with pytest.raises(ImageError, match="fps must be a positive number"):
        write_video(target, mixed[:1], fps=0)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(images.shutil, "which", lambda name: None)
    with pytest.raises(ImageError, match=r"ffmpeg is not on PATH; install it"):
        write_video(target, mixed[:1], fps=7)
    assert shutil.which("ffmpeg") is None  # the patch is what the writer saw
    assert not target.exists()


def test_contact_sheet_layout_and_labels(tmp_path: Path) -> None:
    tiles = [np.full((20, 40, 3), value, np.float32) for value in (0.2, 0.6, 1.0)]
    write_contact_sheet(tmp_path / "plain.png", tiles, columns=2)
    sheet = read_image(tmp_path / "plain.png")
    gap = 4
    assert sheet.shape == (2 * 20 + 3 * gap, 2 * 40 + 3 * gap, 3)
    np.testing.assert_allclose(sheet[gap + 5, gap + 5], 51 / 255)  # first tile
    np.testing.assert_allclose(sheet[gap + 5, 2 * gap + 40 + 5], 153 / 255)  # second, same row
    np.testing.assert_allclose(sheet[2 * gap + 20 + 5, gap + 5], 1.0)  # third, next row
    np.testing.assert_allclose(sheet[2 * gap + 25, 2 * gap + 45], 0.15, atol=1 / 255)  # empty cell
    big = [np.full((120, 240, 3), 0.5, np.float32)] * 2
    write_contact_sheet(tmp_path / "plain_big.png", big, columns=2)
    write_contact_sheet(tmp_path / "labels.png", big, columns=2, labels=["t=0", ""])
    plain = read_image(tmp_path / "plain_big.png")
    labelled = read_image(tmp_path / "labels.png")
    changed = np.any(plain != labelled, axis=2)
    assert changed[:, :124].sum() > 50  # the first cell got its label
    assert not changed[:, 124:].any()  # the empty label draws nothing
    with pytest.raises(ImageError, match="1 labels for 2 images"):
        write_contact_sheet(tmp_path / "x.png", big, columns=2, labels=["a"])
