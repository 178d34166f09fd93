//! The backward's four paths (tile sums over a subgroup first or not; each Gaussian's sums
//! added with native f32 atomics or by compare-exchange): each against the exact sum of
//! its per-tile parts, and the parts against each other. The values themselves are checked
//! against the float64 torch reference in tests/test_render.py.

use super::super::{DeviceOptions, Frame};
use super::*;

/// Unit roundoff of f32 (round to nearest).
const F32_UNIT_ROUNDOFF: f64 = 1.0 / (1u64 << 24) as f64;

/// A renderer for each combination of the optional features; fails (it does not skip) on
/// an adapter that lacks one, since then its two paths cannot be compared.
fn path_renderers() -> Vec<(String, Renderer)> {
    let mut out = Vec::new();
    for subgroups in [true, false] {
        for float_atomics in [true, false] {
            let ctx = GpuContext::with_options(DeviceOptions {
                subgroups,
                float_atomics,
                binding_limit: None,
            })
            .expect("adapter");
            let name = &ctx.adapter.name;
            assert_eq!(
                ctx.has_subgroups(),
                subgroups,
                "{name} has no subgroup operations: the subgroup and plain tile sums cannot \
                 be compared on it"
            );
            assert_eq!(
                ctx.has_float_atomics(),
                float_atomics,
                "{name} has no f32 atomics: the float-atomic and compare-exchange paths \
                 cannot be compared on it"
            );
            let label = format!("subgroups {subgroups}, float atomics {float_atomics}");
            out.push((label, Renderer::new(ctx).expect("renderer")));
        }
    }
    out
}

/// Each Gaussian's ten 2D gradient sums (rasterize_backward.wgsl) after the backward of
/// `frame` for each pixel gradient of `v_pixels`.
fn gaussian_sums(renderer: &mut Renderer, frame: &Frame, v_pixels: &[Vec<f32>]) -> Vec<Vec<f32>> {
    let device = renderer.context().device.clone();
    let n = frame.num_gaussians() as usize;
    let buffer = |len: usize| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: 4 * len as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    };
    let v_buf = buffer(v_pixels[0].len());
    let grads = buffer(23 * n);
    v_pixels
        .iter()
        .map(|v| {
            renderer
                .context()
                .queue
                .write_buffer(&v_buf, 0, bytemuck::cast_slice(v));
            renderer
                .encode_backward(frame, &v_buf, &grads)
                .expect("backward");
            let sums = renderer
                .buffers
                .gaussian_grads
                .buffer
                .clone()
                .expect("sums");
            let words = read(&renderer.ctx, &sums, 10 * n);
            words.into_iter().map(f32::from_bits).collect()
        })
        .collect()
}

/// γ_k = k u / (1 - k u): a float32 sum of k + 1 terms, in any order, is within
/// γ_k · Σ|terms| of the exact sum (Higham, Accuracy and Stability of Numerical
/// Algorithms, 2nd ed., §4.2).
fn gamma(k: usize) -> f64 {
    let ku = k as f64 * F32_UNIT_ROUNDOFF;
    ku / (1.0 - ku)
}

#[test]
fn every_path_adds_each_tiles_total_to_its_gaussian() {
    // Large Gaussians over many 16×16 tiles and a pixel gradient at one random pixel of
    // each tile. A Gaussian's total from one tile is then that one pixel's value, whatever
    // order the tile sums in, so a backward of one tile's pixel gives it exactly; the
    // whole backward adds a Gaussian's m tile totals in whatever order its atomics run, so
    // it must be within γ_{m-1} · Σ|totals| of their exact sum. A lost or misplaced add is
    // as large as a whole tile's total.
    let (w, h) = (96u32, 64u32);
    let (tiles_x, tiles_y) = (w / 16, h / 16);
    let cam = camera(w, h);
    let mut set = random_set(60, 31);
    for s in set.log_scales.iter_mut().flatten() {
        *s += 1.5; // scales of e^-2..e^0 at 3–6 units: tens of pixels
    }
    let settings = RenderSettings {
        background: [0.3, 0.2, 0.1],
        ..Default::default()
    };
    let mut seed = 17u64;
    let mut v_full = vec![0f32; 5 * (w * h) as usize];
    let mut tile_pixels = Vec::new();
    for ty in 0..tiles_y {
        for tx in 0..tiles_x {
            let x = tx * 16 + random_u32(&mut seed) % 16;
            let y = ty * 16 + random_u32(&mut seed) % 16;
            let pixel = (y * w + x) as usize;
            for c in 0..5 {
                v_full[5 * pixel + c] = random_centred(&mut seed);
            }
            tile_pixels.push(pixel);
        }
    }
    // One pixel gradient per tile (that tile's pixel only), then the whole one.
    let mut v_pixels: Vec<Vec<f32>> = tile_pixels
        .iter()
        .map(|&pixel| {
            let mut v_tile = vec![0f32; v_full.len()];
            v_tile[5 * pixel..5 * pixel + 5].copy_from_slice(&v_full[5 * pixel..5 * pixel + 5]);
            v_tile
        })
        .collect();
    v_pixels.push(v_full);
    let mut checked_many_tiles = 0;
    let mut first_path: Option<Vec<Vec<f32>>> = None;
    for (label, mut renderer) in path_renderers() {
        let scene = renderer.upload(&SceneInput::from(&set)).expect("upload");
        let frame = renderer
            .encode_frame(scene, &cam, &settings, None)
            .expect("frame");
        let mut sums = gaussian_sums(&mut renderer, &frame, &v_pixels);
        let whole = sums.pop().expect("the whole backward");
        // Every path runs the same per-pixel WGSL, so a tile's totals agree across paths
        // to a few ulps (on lavapipe bit for bit); an add to the wrong Gaussian or value
        // differs by a whole total.
        let first = first_path.get_or_insert_with(|| sums.clone());
        for (t, (a, b)) in first.iter().zip(&sums).enumerate() {
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                let ulps = 16.0 * F32_UNIT_ROUNDOFF as f32 * x.abs().max(y.abs());
                assert!(
                    (x - y).abs() <= ulps,
                    "{label}: tile {t}, Gaussian {} value {}: {y}, the first path {x}",
                    i / 10,
                    i % 10
                );
            }
        }
        // The per-tile totals on this path (its shaders may round a pixel's value
        // differently from another path's).
        let mut exact = vec![0f64; 10 * set.len()];
        let mut magnitude = vec![0f64; 10 * set.len()];
        let mut terms = vec![0usize; 10 * set.len()];
        for part in sums {
            for (i, value) in part.into_iter().enumerate() {
                exact[i] += value as f64;
                magnitude[i] += value.abs() as f64;
                terms[i] += (value != 0.0) as usize;
            }
        }
        for (i, &got) in whole.iter().enumerate() {
            let bound = gamma(terms[i].saturating_sub(1)) * magnitude[i];
            let error = (got as f64 - exact[i]).abs();
            assert!(
                error <= bound,
                "{label}: Gaussian {} value {}: {got} from the whole backward, {} as the exact \
                 sum of its {} tiles' totals (bound {bound:e})",
                i / 10,
                i % 10,
                exact[i],
                terms[i]
            );
        }
        checked_many_tiles += terms.iter().filter(|&&m| m >= 4).count();
    }
    // Not vacuous: most sums gathered four tiles or more.
    assert!(
        checked_many_tiles > 4 * 10 * set.len() / 2,
        "{checked_many_tiles} sums of 4+ tiles"
    );
}
