//! GPU tests (they run on lavapipe in CI): the sort and scan against CPU versions, and
//! renders of single Gaussians whose footprint is known in closed form; the gradient
//! paths in `gradients.rs`, frames sized on the GPU and the binding limits in `frames.rs`.

mod frames;
mod gradients;

use super::sort::{plan_buffer, scan_plan, scratch_len, SortKernels, SortPlan};
use super::{
    binding_limit, target_texture, GpuContext, GpuScene, RasterError, RenderSettings, Renderer,
};
use crate::camera::Camera;
use crate::gaussians::{GaussianSet, SceneInput};
use glam::DVec3;
use wgpu::util::DeviceExt;

fn storage(device: &wgpu::Device, data: &[u32]) -> wgpu::Buffer {
    let padded: Vec<u32> = data
        .iter()
        .copied()
        .chain(std::iter::repeat_n(0, 64))
        .collect();
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(&padded),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
    })
}

/// The first `len` u32 of `src` (a buffer with COPY_SRC).
fn read(ctx: &GpuContext, src: &wgpu::Buffer, len: usize) -> Vec<u32> {
    let bytes = 4 * len as u64;
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: bytes.max(4),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(src, 0, &staging, 0, bytes);
    ctx.queue.submit([encoder.finish()]);
    staging
        .slice(..)
        .map_async(wgpu::MapMode::Read, |r| r.expect("map"));
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .expect("poll");
    let out = bytemuck::cast_slice(&staging.slice(..).get_mapped_range().expect("mapped")).to_vec();
    out[..len].to_vec()
}

/// A small deterministic generator (xorshift) so the tests need no extra crates.
fn random_u32(seed: &mut u64) -> u32 {
    *seed ^= *seed << 13;
    *seed ^= *seed >> 7;
    *seed ^= *seed << 17;
    (*seed >> 32) as u32
}

/// Uniform in [-0.5, 0.5).
fn random_centred(seed: &mut u64) -> f32 {
    random_u32(seed) as f32 / u32::MAX as f32 - 0.5
}

/// A random pixel gradient for a `width`×`height` frame (H·W·5 values).
fn random_pixel_gradient(width: u32, height: u32, seed: u64) -> Vec<f32> {
    let mut seed = seed;
    (0..5 * width * height)
        .map(|_| random_centred(&mut seed))
        .collect()
}

fn gpu_sort(
    ctx: &GpuContext,
    kernels: &SortKernels,
    keys: &[u32],
    bits: u32,
) -> (Vec<u32>, Vec<u32>) {
    let n = keys.len() as u32;
    let vals: Vec<u32> = (0..n).collect();
    let k = [storage(&ctx.device, keys), storage(&ctx.device, keys)];
    let v = [storage(&ctx.device, &vals), storage(&ctx.device, &vals)];
    let (counts_len, sums_len) = scratch_len(n);
    let counts = storage(&ctx.device, &vec![0; counts_len as usize]);
    let sums = storage(&ctx.device, &vec![0; sums_len as usize]);
    let plan = SortPlan::new(&ctx.device, "test sort plan");
    plan.write(&ctx.queue, n);
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    let out = kernels.encode_sort(
        &ctx.device,
        &mut encoder,
        [&k[0], &k[1]],
        [&v[0], &v[1]],
        &counts,
        &sums,
        &plan,
        bits,
    );
    ctx.queue.submit([encoder.finish()]);
    (
        read(ctx, &k[out], keys.len()),
        read(ctx, &v[out], keys.len()),
    )
}

#[test]
fn radix_sort_matches_a_stable_cpu_sort() {
    let ctx = GpuContext::new().expect("adapter");
    let kernels = SortKernels::new(&ctx.device);
    let mut seed = 0x9e37_79b9_7f4a_7c15;
    for (len, bits, modulus) in [
        (1usize, 32, u32::MAX),
        (7, 32, 3),
        (1000, 32, u32::MAX),
        (5000, 13, 50),
        (70_000, 32, 1000),
        (3000, 4, 16),
    ] {
        let keys: Vec<u32> = (0..len).map(|_| random_u32(&mut seed) % modulus).collect();
        let (sorted_keys, sorted_vals) = gpu_sort(&ctx, &kernels, &keys, bits);
        let mut expected: Vec<(u32, u32)> = keys.iter().copied().zip(0..).collect();
        expected.sort_by_key(|&(k, _)| k); // stable: ties keep index order
        let (ek, ev): (Vec<u32>, Vec<u32>) = expected.into_iter().unzip();
        assert_eq!(sorted_keys, ek, "keys, len {len}");
        assert_eq!(sorted_vals, ev, "values (stability), len {len}");
    }
}

#[test]
fn scan_matches_a_cpu_prefix_sum() {
    let ctx = GpuContext::new().expect("adapter");
    let kernels = SortKernels::new(&ctx.device);
    let mut seed = 12345;
    for len in [1usize, 5, 1024, 1025, 300_000] {
        let data: Vec<u32> = (0..len).map(|_| random_u32(&mut seed) % 17).collect();
        let buf = storage(&ctx.device, &data);
        let (_, sums_len) = scratch_len(len as u32);
        let sums = storage(&ctx.device, &vec![0; sums_len as usize]);
        let plan = plan_buffer(&ctx.device, "test scan plan");
        ctx.queue
            .write_buffer(&plan, 0, bytemuck::bytes_of(&scan_plan(len as u32)));
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        kernels.encode_scan(&ctx.device, &mut encoder, &buf, &sums, &plan);
        ctx.queue.submit([encoder.finish()]);
        let got = read(&ctx, &buf, len);
        let expected: Vec<u32> = data
            .iter()
            .scan(0, |acc, &v| {
                let out = *acc;
                *acc += v;
                Some(out)
            })
            .collect();
        assert_eq!(got, expected, "len {len}");
    }
}

/// One isotropic Gaussian with SH DC (1, 0, -1).
fn one_gaussian(mean: [f32; 3], log_scale: f32, opacity_logit: f32) -> GaussianSet {
    GaussianSet {
        sh_degree: 0,
        means: vec![mean],
        log_scales: vec![[log_scale; 3]],
        quats: vec![[1.0, 0.0, 0.0, 0.0]],
        opacity_logits: vec![opacity_logit],
        sh: vec![1.0, 0.0, -1.0],
    }
}

/// `n` random SH-degree-1 Gaussians in front of [`camera`].
fn random_set(n: usize, seed: u64) -> GaussianSet {
    let mut state = seed.max(1);
    let mut uniform =
        |lo: f32, hi: f32| lo + (hi - lo) * random_u32(&mut state) as f32 / u32::MAX as f32;
    let mut set = GaussianSet::with_capacity(1, n);
    for _ in 0..n {
        set.means
            .push([uniform(3.0, 6.0), uniform(-2.0, 2.0), uniform(-1.5, 1.5)]);
        set.log_scales.push([
            uniform(-3.5, -1.5),
            uniform(-3.5, -1.5),
            uniform(-3.5, -1.5),
        ]);
        set.quats.push([
            uniform(-1.0, 1.0),
            uniform(-1.0, 1.0),
            uniform(-1.0, 1.0),
            uniform(-1.0, 1.0),
        ]);
        set.opacity_logits.push(uniform(-2.0, 3.0));
        for _ in 0..12 {
            set.sh.push(uniform(-1.0, 1.0));
        }
    }
    set
}

fn concat(a: &GaussianSet, b: &GaussianSet) -> GaussianSet {
    let mut out = a.clone();
    out.extend_from(b);
    out
}

fn camera(width: u32, height: u32) -> Camera {
    Camera::from_fov(60.0, width, height, DVec3::ZERO, DVec3::X, DVec3::Z)
}

#[test]
fn centred_gaussian_renders_its_closed_form_footprint() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let (log_scale, opacity_logit, z) = (-1.0f32, 2.0f32, 5.0f64);
    let g = one_gaussian([z as f32, 0.0, 0.0], log_scale, opacity_logit);
    let settings = RenderSettings::default();
    let (w, h) = (40u32, 30u32);
    let cam = camera(w, h);
    let (pixels, isects) = renderer
        .forward(&SceneInput::from(&g), &cam, &settings)
        .expect("render");
    assert!(isects >= 1);
    // On the optical axis an isotropic Gaussian of scale s at depth z projects to variance
    // (f s / z)² (+ 0.3 px² of low-pass) about the image centre (20, 15), a pixel corner.
    let variance = (cam.fx * (log_scale as f64).exp() / z).powi(2) + 0.3;
    let opacity = 1.0 / (1.0 + (-opacity_logit as f64).exp());
    // Its footprint as the projection reports it: 3·sqrt of the larger eigenvalue, which
    // the kernel keeps sqrt(0.1) above the mean one (here the variance), rounded up.
    let footprints = renderer
        .footprints(&SceneInput::from(&g), &cam, &settings)
        .expect("footprints");
    let radius = (3.0 * (variance + 0.1f64.sqrt()).sqrt()).ceil();
    assert_eq!(footprints, vec![[20.0, 15.0, radius as f32]]);
    let mut drawn = 0;
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = (x as f64 + 0.5 - 20.0, y as f64 + 0.5 - 15.0);
            let power = -0.5 * (dx * dx + dy * dy) / variance;
            let alpha = opacity * power.exp();
            let px = &pixels[((y * w + x) as usize) * 5..][..5];
            assert!(
                px[3] == 0.0 || (dx * dx + dy * dy).sqrt() <= radius,
                "pixel ({x}, {y}) is drawn beyond the footprint"
            );
            if power < -4.5 + 1e-4 || alpha < 1.0 / 255.0 + 1e-6 {
                // Outside the 3σ ellipse or too faint: nothing drawn (away from the edge).
                if power < -4.5 - 1e-4 || alpha < 1.0 / 255.0 - 1e-6 {
                    assert_eq!(px[3], 0.0, "pixel ({x}, {y})");
                }
                continue;
            }
            drawn += 1;
            assert!((px[3] as f64 - alpha).abs() < 1e-5, "alpha at ({x}, {y})");
            // Expected depth D / alpha is z; colour 0.5 + C0 · (1, 0, -1) on black.
            assert!(
                (px[4] as f64 / alpha - z).abs() < 1e-4,
                "depth at ({x}, {y})"
            );
            let c0 = crate::gaussians::SH_C0 as f64;
            for (got, colour) in px[..3].iter().zip([0.5 + c0, 0.5, 0.5 - c0]) {
                assert!(
                    (*got as f64 - colour * alpha).abs() < 1e-5,
                    "rgb at ({x}, {y})"
                );
            }
        }
    }
    assert!(drawn > 50, "only {drawn} pixels drawn");
}

#[test]
fn gaussians_behind_the_camera_or_invalid_are_culled() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let settings = RenderSettings {
        background: [0.25, 0.5, 0.75],
        antialiased: true,
        ..Default::default()
    };
    for g in [
        one_gaussian([-5.0, 0.0, 0.0], 0.0, 5.0),
        one_gaussian([0.005, 0.0, 0.0], 0.0, 5.0),
        one_gaussian([f32::NAN, 0.0, 0.0], 0.0, 5.0),
        one_gaussian([5.0, 0.0, 0.0], f32::INFINITY, 5.0),
    ] {
        let (pixels, isects) = renderer
            .forward(&SceneInput::from(&g), &camera(17, 13), &settings)
            .expect("render");
        assert_eq!(isects, 0);
        for px in pixels.chunks(5) {
            assert_eq!(px, &[0.25, 0.5, 0.75, 0.0, 0.0]);
        }
    }
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let mut g = one_gaussian([5.0, 0.0, 0.0], 0.0, 0.0);
    g.sh.push(0.0);
    let settings = RenderSettings::default();
    assert!(renderer
        .forward(&SceneInput::from(&g), &camera(8, 8), &settings)
        .is_err());
    let g = one_gaussian([5.0, 0.0, 0.0], 0.0, 0.0);
    assert!(renderer
        .backward(&SceneInput::from(&g), &camera(8, 8), &settings, &[0.0; 3])
        .is_err());
}

/// The forward's colours quantised as `Renderer::draw` stores them.
fn quantised(pixels: &[f32]) -> Vec<u8> {
    pixels
        .chunks_exact(5)
        .flat_map(|p| {
            let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            [q(p[0]), q(p[1]), q(p[2]), 255]
        })
        .collect()
}

fn assert_close_rgba(got: &[u8], want: &[u8], what: &str) {
    assert_eq!(got.len(), want.len());
    let worst = got
        .iter()
        .zip(want)
        .map(|(a, b)| a.abs_diff(*b))
        .max()
        .unwrap_or(0);
    // Rounding at exactly half a level may differ between the GPU's and the CPU's.
    assert!(worst <= 1, "{what}: largest difference {worst} levels");
}

#[test]
fn a_gpu_scene_draws_what_the_forward_renders() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let device = renderer.context().device.clone();
    let queue = renderer.context().queue.clone();
    let (w, h) = (45u32, 33u32);
    let cam = camera(w, h);
    let target = target_texture(&device, w, h);
    let static_set = random_set(300, 1);
    let mut scene_on_gpu = GpuScene::new(&device, 500, 4).expect("gpu scene");
    scene_on_gpu
        .write(&queue, 0, &SceneInput::from(&static_set))
        .expect("static set");
    let settings = RenderSettings {
        background: [0.1, 0.2, 0.3],
        ..Default::default()
    };
    // Dynamic sets of different sizes replace each other after the static set.
    for (count, seed) in [(150, 2), (40, 3), (200, 4)] {
        let dynamic = random_set(count, seed);
        scene_on_gpu
            .write(&queue, static_set.len(), &SceneInput::from(&dynamic))
            .expect("dynamic set");
        assert_eq!(scene_on_gpu.len(), 300 + count);
        renderer
            .draw(&scene_on_gpu, &cam, &settings, &target)
            .expect("draw");
        let got = renderer.read_rgba8(&target).expect("read back");
        assert!(
            got.chunks(4).any(|p| p != [26, 51, 77, 255]),
            "nothing drawn"
        );
        let whole = concat(&static_set, &dynamic);
        let (pixels, _) = renderer
            .forward(&SceneInput::from(&whole), &cam, &settings)
            .expect("forward");
        assert_close_rgba(&got, &quantised(&pixels), &format!("{count} dynamic"));
    }
    // The splat scale is the same as scaling the stored Gaussians.
    let scaled = RenderSettings {
        splat_scale: 1.7,
        ..settings
    };
    renderer
        .draw(&scene_on_gpu, &cam, &scaled, &target)
        .expect("draw");
    let got = renderer.read_rgba8(&target).expect("read back");
    let mut whole = concat(&static_set, &random_set(200, 4));
    for s in whole.log_scales.iter_mut().flatten() {
        *s += 1.7f32.ln();
    }
    let (pixels, _) = renderer
        .forward(&SceneInput::from(&whole), &cam, &settings)
        .expect("forward");
    assert_close_rgba(&got, &quantised(&pixels), "splat scale 1.7");
}

#[test]
fn a_gpu_scene_refuses_what_does_not_fit() {
    let renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let device = &renderer.context().device;
    let queue = &renderer.context().queue;
    let mut scene_on_gpu = GpuScene::new(device, 10, 4).expect("gpu scene");
    let eight = random_set(8, 5);
    assert!(scene_on_gpu
        .write(queue, 0, &SceneInput::from(&eight))
        .is_ok());
    // Past the capacity, or leaving a gap after what is written.
    assert!(scene_on_gpu
        .write(queue, 3, &SceneInput::from(&eight))
        .is_err());
    assert!(scene_on_gpu
        .write(queue, 9, &SceneInput::from(&random_set(1, 6)))
        .is_err());
    // Another SH degree.
    let dc_only = one_gaussian([5.0, 0.0, 0.0], 0.0, 0.0);
    assert!(scene_on_gpu
        .write(queue, 8, &SceneInput::from(&dc_only))
        .is_err());
    assert_eq!(scene_on_gpu.len(), 8);
    assert!(GpuScene::new(device, 10, 5).is_err());
    let allowed = binding_limit(device);
    let over = (allowed / GpuScene::bytes_for(1, 16)) as usize + 1;
    if over < (u32::MAX / 64) as usize {
        assert!(matches!(
            GpuScene::new(device, over, 16),
            Err(RasterError::TooLarge { .. })
        ));
    }
}

#[test]
fn draw_checks_its_target() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let device = renderer.context().device.clone();
    let scene_on_gpu = GpuScene::new(&device, 4, 1).expect("scene_on_gpu scene");
    let wrong_size = target_texture(&device, 8, 9);
    let settings = RenderSettings::default();
    assert!(renderer
        .draw(&scene_on_gpu, &camera(8, 8), &settings, &wrong_size)
        .is_err());
    let nan_scale = RenderSettings {
        splat_scale: f32::NAN,
        ..settings
    };
    let target = target_texture(&device, 8, 8);
    assert!(renderer
        .draw(&scene_on_gpu, &camera(8, 8), &nan_scale, &target)
        .is_err());
    // An empty scene draws the background.
    renderer
        .draw(&scene_on_gpu, &camera(8, 8), &settings, &target)
        .expect("empty draw");
    assert!(renderer
        .read_rgba8(&target)
        .expect("read back")
        .chunks(4)
        .all(|p| p == [0, 0, 0, 255]));
}
