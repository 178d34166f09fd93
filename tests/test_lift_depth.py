"""Depth backends: layout prior, depth file, transformers models loaded by path; L_sem features."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from pano4d.config import DepthConfig, FeaturesConfig
from pano4d.images import write_image
from pano4d.lift.depth import (
    DepthError,
    FileDepth,
    TransformersDepth,
    disparity_to_depth,
    layout_depth,
    layout_prior,
    make_depth_backend,
    sample_equirect_depth,
)
from pano4d.lift.features import FeatureError, make_feature_model
from pano4d.lift.random_dinov2 import random_feature_model
from pano4d.sphere import equirect_directions, view_layout

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _quiet_transformers() -> None:
    import transformers

    transformers.logging.set_verbosity_error()


def test_layout_prior_is_the_ground_plane_below_and_the_dome_above() -> None:
    prior = layout_prior(64, 32, camera_height=1.6, far=500.0)
    dirs = equirect_directions(64, 32, torch.float64)
    down = -dirs[..., 2]
    below = down > 1.6 / 500.0
    # A point at ray length r along d sits r·d_z below the camera: exactly the camera height.
    assert torch.allclose(prior[below].double() * down[below], torch.full_like(down[below], 1.6),
                          rtol=1e-5)  # fmt: skip
    assert torch.all(prior[dirs[..., 2] >= 0] == 500.0)
    assert torch.isfinite(prior).all() and prior.max() <= 500.0


def test_layout_refinement_keeps_a_flat_image_at_the_prior_and_follows_image_edges() -> None:
    flat = torch.full((32, 64, 3), 0.5)
    refined = layout_depth(flat, 1.6, 500.0)
    prior = layout_prior(64, 32, 1.6, 500.0)
    # Uniform guide: the guided filter is a plain box mean of log depth, so away from the
    # horizon (where the prior jumps from the ground to the dome) it stays on the prior.
    rows = torch.cat([torch.arange(0, 12), torch.arange(21, 32)])
    assert ((refined[rows].log() - prior[rows].log()).abs() < 0.05).all()
    # A bright object below the horizon against dark ground pulls its depth together.
    image = torch.full((32, 64, 3), 0.2)
    image[18:26, 20:28] = 0.9
    depth = layout_depth(image, 1.6, 500.0, radius=3)
    inside = depth[18:26, 20:28].log()
    assert inside.std() < prior[18:26, 20:28].log().std()
    assert torch.isfinite(depth).all() and (depth > 0).all()


def test_file_backend_reads_ray_length_and_keeps_extreme_depths_finite(tmp_path: Path) -> None:
    depth = np.full((32, 64), 7.0, dtype=np.float32)
    depth[:4] = 1e4  # near the zenith: far
    depth[-4:] = 0.1  # near the nadir: very near
    path = tmp_path / "depth.exr"
    write_image(path, depth[..., None])
    backend = make_depth_backend(DepthConfig(backend="file", path=path, far=1e4))
    assert isinstance(backend, FileDepth)
    cams = view_layout(20, 80.0, 16)
    views = backend.view_depth(torch.zeros(32, 64, 3), cams)
    assert views.shape == (20, 16, 16)
    assert torch.isfinite(views).all()
    assert views.min() >= 0.1 * 0.999 and views.max() <= 1e4 * 1.001
    # The horizontal views see the constant band: ray length 7 everywhere, not z-depth.
    horizontal = [i for i, c in enumerate(cams) if abs(float(c.forward[2])) < 0.2]
    assert torch.allclose(views[horizontal][:, 6:10, 6:10], torch.tensor(7.0), rtol=1e-4)
    # A different frame size is resampled, in log space.
    assert backend.equirect(16, 32).shape == (16, 32)


def test_disparity_becomes_inverse_depth_with_a_finite_far() -> None:
    disparity = torch.tensor([[[4.0, 2.0], [1.0, 0.0]]])
    depth = disparity_to_depth(disparity, far_ratio=100.0)
    assert torch.isfinite(depth).all()
    assert depth[0, 1, 1] == pytest.approx(100.0)  # zero disparity (sky): far, not infinite
    # Up to one scale, depth is 1 / disparity.
    ratio = depth[0, 0, 0] / depth[0, 0, 1]
    assert float(ratio) == pytest.approx(0.5, rel=1e-5)
    assert float(depth[0, 1, 0] / depth[0, 0, 0]) == pytest.approx(4.0, rel=1e-5)


def _tiny_dpt(folder: Path) -> Path:
    from transformers import AutoModelForDepthEstimation, DPTConfig

    config = DPTConfig(
        hidden_size=16, num_hidden_layers=4, num_attention_heads=2, intermediate_size=32,
        image_size=32, patch_size=8, neck_hidden_sizes=[8, 8, 8, 8], fusion_hidden_size=8,
        backbone_out_indices=[0, 1, 2, 3], head_hidden_size=4,
    )  # fmt: skip
    torch.manual_seed(0)
    AutoModelForDepthEstimation.from_config(config).save_pretrained(folder)
    return folder


def _tiny_depth_anything(folder: Path) -> Path:
    from transformers import AutoModelForDepthEstimation, DepthAnythingConfig, Dinov2Config

    backbone = Dinov2Config(
        hidden_size=16, num_hidden_layers=4, num_attention_heads=2, intermediate_size=32,
        patch_size=14, image_size=28, out_features=["stage1", "stage2", "stage3", "stage4"],
        reshape_hidden_states=False,
    )  # fmt: skip
    config = DepthAnythingConfig(
        backbone_config=backbone, neck_hidden_sizes=[8, 8, 8, 8], fusion_hidden_size=8,
        reassemble_hidden_size=16, head_hidden_size=4, patch_size=14,
    )  # fmt: skip
    torch.manual_seed(0)
    AutoModelForDepthEstimation.from_config(config).save_pretrained(folder)
    return folder


@pytest.mark.parametrize("build", [_tiny_dpt, _tiny_depth_anything], ids=["dpt", "depth_anything"])
def test_transformers_models_load_by_path_and_give_positive_ray_length(
    tmp_path: Path, build
) -> None:  # type: ignore[no-untyped-def]
    _quiet_transformers()
    folder = build(tmp_path / "model")
    backend = make_depth_backend(DepthConfig(backend="dpt", weights=folder, far=100.0,
                                             camera_height=1.0))  # fmt: skip
    assert isinstance(backend, TransformersDepth) and not backend.metric
    cams = view_layout(4, 80.0, 20)
    frame = torch.rand(32, 64, 3, generator=torch.Generator().manual_seed(1))
    views = backend.view_depth(frame, cams)
    assert views.shape == (4, 20, 20)
    assert torch.isfinite(views).all() and (views > 0).all()
    # Relative disparity → depth normalised per view, capped at far / camera_height; the
    # conversion to ray length makes corners longer than z by the ray factor (≤ 1/cos 40°·√2).
    assert views.max() <= 100.0 * cams[0].z_to_ray_factor().max() * 1.0001
    z = backend.predict_z(torch.rand(2, 3, 20, 20))
    assert z.shape == (2, 20, 20) and (z > 0).all()


def test_dpt_backend_refuses_a_folder_without_a_model(tmp_path: Path) -> None:
    with pytest.raises(DepthError, match=r"no config\.json"):
        TransformersDepth(tmp_path, far_ratio=100.0)


def test_dinov2_features_load_by_path_and_pass_gradients_to_the_image(tmp_path: Path) -> None:
    model = random_feature_model(tmp_path, patch_size=14, image_size=28, layers=2)
    image = torch.rand(24, 24, 3, requires_grad=True)
    cls = model.cls(image)
    assert cls.shape == (16,)
    # Not cls.sum(): the CLS token leaves a LayerNorm, whose output sums to its bias
    # whatever the image, so that sum's gradient is zero up to rounding.
    (cls * torch.arange(16.0)).sum().backward()
    assert image.grad is not None and float(image.grad.abs().sum()) > 0
    assert make_feature_model(FeaturesConfig()) is None
    with pytest.raises(FeatureError, match=r"no config\.json"):
        make_feature_model(FeaturesConfig(backend="dinov2", weights=tmp_path))


def test_sampled_view_depth_of_a_constant_sphere_is_constant() -> None:
    depth = torch.full((16, 32), 3.0)
    views = sample_equirect_depth(depth, view_layout(6, 80.0, 8))
    assert torch.allclose(views, torch.tensor(3.0), rtol=1e-5)
    assert math.isfinite(float(views.sum()))
