"""Static pixels stay the input's, bit for bit, in the frames the animating phase writes.

In memory the claim holds by construction: ``enforce_static`` (and ``animate_svd``'s blend)
select the input wherever the blend weight is 0. What that selection does not cover is the
route to the files the lifting phase reads: the frame format, its bit depth and the decoder.
So the frames are read back from disk and compared, as bits, with the input file as
``read_panorama`` decodes it, for every input format a user can give. (That the denoiser's
own latent keeps the input where no active view looks is tested in test_denoiser.py.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pano4d.animate import pipeline
from pano4d.animate.pipeline import run_animate
from pano4d.config import validate_config
from pano4d.images import read_panorama, write_image
from pano4d.regions import build_regions

WIDTH, HEIGHT = 512, 256


@pytest.mark.parametrize(("suffix", "bits"), [(".png", 8), (".png", 16), (".exr", 32)])
def test_written_frames_keep_the_static_pixels_of_every_input_format(
    tmp_path: Path, suffix: str, bits: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """8-bit PNG stands for JPEG too (both decode to k/255); a half EXR decodes to floats
    that a float EXR frame holds exactly, so the float EXR is the one that can fail."""
    # The preview video and the motion metrics (optical flow) are not what is tested here
    # and take most of the time; the frames are written before them.
    monkeypatch.setattr(pipeline, "_write_video_and_measure", lambda *_: {})
    rng = np.random.default_rng(0)
    # Full-precision floats: every bit of an EXR input matters, and the PNG/JPEG writers
    # quantise them to what the file holds.
    image = rng.random((HEIGHT, WIDTH, 3), dtype=np.float32)
    write_image(tmp_path / f"panorama{suffix}", image, bits=bits)
    cfg = validate_config(
        {
            "panorama": f"panorama{suffix}",
            "regions": [{"box": [480, 60, 64, 120], "motion": {"speed": 3.0}}],  # across the seam
            "animate": {"frames": 2, "border_px": 4},
            "output": "out",
        },
        base_dir=tmp_path,
    )
    result = run_animate(cfg, progress=False)
    panorama = read_panorama(cfg.panorama)
    still = build_regions(cfg, WIDTH, HEIGHT).blend.numpy() == 0
    assert 0.5 < still.mean() < 0.99
    frames = list(result.store.frames())
    for t, frame in enumerate(frames):
        assert frame.dtype == np.float32 and frame.shape == panorama.shape
        assert np.array_equal(frame[still].view(np.uint32), panorama[still].view(np.uint32)), t
    moved = frames[-1][~still] - panorama[~still]
    assert float(np.abs(moved).mean()) > 0.01
