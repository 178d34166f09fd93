//! Frames sized on the GPU (the tile plan, overflow and its recovery, the device-side
//! calls a training loop chains) and the storage-binding limits, reached cheaply on any
//! adapter through a deliberately small one.

use super::super::gpu::grid;
use super::super::sort::sort_plans;
use super::super::{DeviceOptions, SceneBuffer, STATUS_DRAWN, TILE_SIZE};
use super::*;

fn renderer_with_limit(limit: Option<u64>) -> Renderer {
    let ctx = GpuContext::with_options(DeviceOptions {
        binding_limit: limit,
        ..DeviceOptions::from_env()
    })
    .expect("adapter");
    Renderer::new(ctx).expect("renderer")
}

/// A buffer of `data` for the device-side calls (pixel gradients, gradients).
fn floats(renderer: &Renderer, data: &[f32]) -> wgpu::Buffer {
    renderer
        .context()
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::cast_slice(data),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        })
}

fn read_floats(renderer: &Renderer, src: &wgpu::Buffer, len: usize) -> Vec<f32> {
    read(&renderer.ctx, src, len)
        .into_iter()
        .map(f32::from_bits)
        .collect()
}

/// Two backwards of one frame differ only in the order their atomics add the tiles'
/// totals (gradients.rs checks that against its exact bound); this checks plumbing, so
/// loosely: to 1e-4 of each value, or of 0.01 for smaller ones.
fn assert_same_up_to_tile_order(got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len());
    for (a, b) in got.iter().zip(want) {
        assert!((a - b).abs() <= 1e-4 * b.abs().max(1e-2), "{a} vs {b}");
    }
}

fn settings() -> RenderSettings {
    RenderSettings {
        background: [0.25, 0.5, 0.75],
        ..Default::default()
    }
}

#[test]
fn a_frame_that_overflows_draws_nothing_and_is_counted_until_there_is_room() {
    let mut renderer = renderer_with_limit(None);
    let (w, h) = (64u32, 48u32);
    let cam = camera(w, h);
    let small = random_set(3, 41);
    let large = random_set(600, 42);
    let (want, count) = renderer_with_limit(None)
        .forward(&SceneInput::from(&large), &cam, &settings())
        .expect("forward");
    // The first frame sizes the intersection buffers for the small scene.
    let scene = renderer.upload(&SceneInput::from(&small)).expect("upload");
    renderer
        .encode_frame(scene, &cam, &settings(), None)
        .expect("frame");
    let capacity = renderer.intersection_capacity();
    assert!(
        capacity > 0 && capacity < count,
        "capacity {capacity}, count {count}"
    );
    // The large scene does not fit: the frame draws the background only, says so on the
    // device and is counted; its backward gives zero gradients.
    let scene = renderer.upload(&SceneInput::from(&large)).expect("upload");
    let frame = renderer
        .encode_frame(scene, &cam, &settings(), None)
        .expect("frame");
    let status = read(&renderer.ctx, renderer.frame_status(), 4);
    assert_eq!((status[2], status[STATUS_DRAWN]), (count, 0));
    let pixels = read_floats(&renderer, renderer.frame_pixels(), 5 * (w * h) as usize);
    assert!(pixels.chunks(5).all(|p| p == [0.25, 0.5, 0.75, 0.0, 0.0]));
    let v_pixels = floats(&renderer, &vec![1.0; 5 * (w * h) as usize]);
    let grads = floats(&renderer, &vec![f32::NAN; 23 * large.len()]);
    renderer
        .encode_backward(&frame, &v_pixels, &grads)
        .expect("backward");
    assert!(read_floats(&renderer, &grads, 23 * large.len())
        .iter()
        .all(|g| *g == 0.0));
    // The check reports it and makes room; the same frame then draws what forward draws.
    let check = renderer.check_intersections().expect("check");
    assert_eq!((check.overflowed, check.max_intersections), (1, count));
    assert!(check.capacity >= count + count / 4, "{check:?}");
    let scene = renderer.upload(&SceneInput::from(&large)).expect("upload");
    renderer
        .encode_frame(scene, &cam, &settings(), None)
        .expect("frame");
    assert_eq!(
        read(&renderer.ctx, renderer.frame_status(), 4)[STATUS_DRAWN],
        1
    );
    assert_eq!(
        read_floats(&renderer, renderer.frame_pixels(), want.len()),
        want,
        "the frame after the check"
    );
    // Overflows are counted once: nothing new since the last check.
    assert_eq!(renderer.check_intersections().expect("check").overflowed, 0);
}

#[test]
fn the_gpu_sizes_the_tile_sort_as_the_host_would() {
    let mut renderer = renderer_with_limit(None);
    renderer.reserve_intersections(200_000).expect("room");
    let cam = camera(80, 64);
    // Up to tens of thousands of intersections: sorts of several blocks, and digit-count
    // scans of several blocks too.
    for (n, seed, grow) in [(0, 1, 0.0), (1, 2, 0.0), (700, 3, 0.0), (4000, 4, 3.0)] {
        let mut set = random_set(n, seed);
        for s in set.log_scales.iter_mut().flatten() {
            *s += grow;
        }
        let scene = renderer.upload(&SceneInput::from(&set)).expect("upload");
        renderer
            .encode_frame(scene, &cam, &settings(), None)
            .expect("frame");
        let m = read(&renderer.ctx, renderer.frame_status(), 4)[2];
        let (sort, scan) = sort_plans(m);
        let sort: [u32; 5] = bytemuck::cast(sort);
        let scan: [u32; 5] = bytemuck::cast(scan);
        let plan = &renderer.buffers.tile_plan;
        let words = read(&renderer.ctx, &plan.sort, 8);
        assert_eq!(words[..5], sort, "{n} Gaussians, {m} intersections");
        assert_eq!(words[5..], grid(m.div_ceil(256)), "ranges of {m}");
        assert_eq!(
            read(&renderer.ctx, &plan.scan, 5),
            scan,
            "{m} intersections"
        );
        if grow > 0.0 {
            assert!(scan[1] > 1, "{m} intersections: one scan block");
        }
    }
}

#[test]
fn forward_and_backward_encode_an_overflowed_frame_again() {
    let (w, h) = (48u32, 40u32);
    let cam = camera(w, h);
    let large = random_set(500, 51);
    let input = SceneInput::from(&large);
    let v_pixels = random_pixel_gradient(w, h, 9);
    let mut fresh = renderer_with_limit(None);
    let want = fresh.forward(&input, &cam, &settings()).expect("forward");
    let want_grads = fresh
        .backward(&input, &cam, &settings(), &v_pixels)
        .expect("backward");
    for call in ["forward", "backward"] {
        // A renderer sized by a tiny scene first.
        let mut renderer = renderer_with_limit(None);
        renderer
            .forward(&SceneInput::from(&random_set(2, 52)), &cam, &settings())
            .expect("small");
        assert!(renderer.intersection_capacity() < want.1);
        if call == "forward" {
            assert_eq!(
                renderer
                    .forward(&input, &cam, &settings())
                    .expect("forward"),
                want
            );
        } else {
            let grads = renderer
                .backward(&input, &cam, &settings(), &v_pixels)
                .expect("backward");
            assert_same_up_to_tile_order(&grads.means, &want_grads.means);
        }
        // Those calls check their own frames: nothing is left for check_intersections.
        assert_eq!(renderer.check_intersections().expect("check").overflowed, 0);
    }
}

#[test]
fn the_device_side_calls_give_what_the_waiting_calls_give() {
    // What a training loop chains: encode_frame, its pixels read on the device, a pixel
    // gradient written on the device, encode_backward into a gradient buffer.
    let mut renderer = renderer_with_limit(None);
    let (w, h) = (40u32, 32u32);
    let cam = camera(w, h);
    let set = random_set(200, 61);
    let input = SceneInput::from(&set);
    let v = random_pixel_gradient(w, h, 5);
    let (want_pixels, _) = renderer
        .forward(&input, &cam, &settings())
        .expect("forward");
    let want = renderer
        .backward(&input, &cam, &settings(), &v)
        .expect("backward");
    let scene = renderer.upload(&input).expect("upload");
    let frame = renderer
        .encode_frame(scene, &cam, &settings(), None)
        .expect("frame");
    assert_eq!(frame.size(), (w, h));
    assert_eq!(frame.num_gaussians(), 200);
    let pixels = read_floats(&renderer, renderer.frame_pixels(), want_pixels.len());
    assert_eq!(pixels, want_pixels);
    let v_buf = floats(&renderer, &v);
    let grads = floats(&renderer, &vec![0.0; 23 * set.len()]);
    renderer
        .encode_backward(&frame, &v_buf, &grads)
        .expect("backward");
    let got = read_floats(&renderer, &grads, 23 * set.len());
    let want_flat: Vec<f32> = [
        &want.means,
        &want.log_scales,
        &want.quats,
        &want.opacity_logits,
        &want.sh,
    ]
    .into_iter()
    .flatten()
    .copied()
    .collect();
    assert_same_up_to_tile_order(&got, &want_flat);
    // A gradient buffer too small for the scene is refused, not overrun.
    let short = floats(&renderer, &[0.0; 64]);
    assert!(matches!(
        renderer.encode_backward(&frame, &v_buf, &short),
        Err(RasterError::InvalidInput(_))
    ));
}

#[test]
fn a_scene_just_under_the_binding_limit_renders() {
    // A 4 MiB limit on any adapter: a scene within 1 % of it renders and trains (the
    // renderer's growable buffers must add no headroom past the binding), one Gaussian
    // more than fits is refused.
    let limit = 4u64 << 20;
    let mut renderer = renderer_with_limit(Some(limit));
    assert_eq!(binding_limit(&renderer.context().device), limit);
    let per_gaussian = GpuScene::bytes_for(1, 16);
    let n = (limit as f64 * 0.99 / per_gaussian as f64) as usize;
    let mut set = random_set(n, 21);
    set.sh_degree = 3;
    set.sh = vec![0.1; n * 16 * 3];
    let cam = camera(16, 16);
    let (pixels, isects) = renderer
        .forward(&SceneInput::from(&set), &cam, &RenderSettings::default())
        .expect("a scene under the limit renders");
    assert!(isects > 0 && pixels.iter().all(|v| v.is_finite()));
    let grads = renderer
        .backward(
            &SceneInput::from(&set),
            &cam,
            &RenderSettings::default(),
            &vec![1.0; pixels.len()],
        )
        .expect("and has gradients");
    assert!(grads.means.iter().any(|g| *g != 0.0));
    let over = (limit / per_gaussian) as usize + 1;
    let mut set = random_set(over, 22);
    set.sh_degree = 3;
    set.sh = vec![0.1; over * 16 * 3];
    assert!(matches!(
        renderer.forward(&SceneInput::from(&set), &cam, &RenderSettings::default()),
        Err(RasterError::TooLarge { .. })
    ));
}

#[test]
fn intersections_just_under_the_binding_limit_render() {
    // Gaussians that cover every tile: 4 bytes per intersection outgrow the 56 bytes per
    // Gaussian of the scene, so the per-intersection arrays are the first to reach the
    // limit. With the limit at exactly 4 bytes × the frame's intersections it renders (and
    // trains); 4 bytes less, it is refused with a message, whether the frame is the
    // renderer's first or comes after smaller ones.
    let (w, h) = (128u32, 96u32);
    let cam = camera(w, h);
    let mut set = random_set(1500, 71);
    set.sh_degree = 0;
    set.sh = vec![0.2; set.len() * 3];
    for s in set.log_scales.iter_mut().flatten() {
        *s += 3.5;
    }
    let input = SceneInput::from(&set);
    let (want, m) = renderer_with_limit(None)
        .forward(&input, &cam, &settings())
        .expect("unlimited");
    assert!(m as usize > 40 * set.len(), "{m} intersections");
    let mut at_limit = renderer_with_limit(Some(4 * m as u64));
    assert_eq!(
        at_limit
            .forward(&input, &cam, &settings())
            .expect("at the limit"),
        (want, m)
    );
    let grads = at_limit
        .backward(&input, &cam, &settings(), &vec![1.0; (5 * w * h) as usize])
        .expect("backward at the limit");
    assert!(grads.means.iter().any(|g| *g != 0.0));
    for warm_up in [false, true] {
        let mut over = renderer_with_limit(Some(4 * m as u64 - 4));
        if warm_up {
            over.forward(&SceneInput::from(&random_set(3, 72)), &cam, &settings())
                .expect("a small scene");
        }
        match over.forward(&input, &cam, &settings()) {
            Err(RasterError::Gpu(message)) => assert!(
                message.contains(&format!("{m} tile intersections need more")),
                "{message}"
            ),
            other => panic!("expected the intersection limit, got {other:?}"),
        }
    }
}

#[test]
fn a_frame_over_a_static_render_copies_the_tiles_of_the_static_set_alone() {
    let mut renderer = renderer_with_limit(None);
    renderer.reserve_intersections(50_000).expect("room");
    let (w, h) = (96u32, 64u32);
    let cam = camera(w, h);
    let len = 5 * (w * h) as usize;
    // A static set over the whole view and three trained Gaussians: most tiles hold the
    // static set alone.
    let mut scene_set = random_set(400, 61);
    let n_static = scene_set.len() as u32;
    scene_set.extend_from(&random_set(3, 62));
    let scene = SceneBuffer {
        n_static,
        ..renderer
            .upload(&SceneInput::from(&scene_set))
            .expect("upload")
    };
    let static_set = SceneBuffer {
        len: n_static,
        ..scene.clone()
    };
    renderer
        .encode_frame(static_set, &cam, &settings(), None)
        .expect("static set's frame");
    let static_pixels = read_floats(&renderer, renderer.frame_pixels(), len);
    let frame = renderer
        .encode_frame(scene.clone(), &cam, &settings(), None)
        .expect("blended frame");
    let blended = read_floats(&renderer, renderer.frame_pixels(), len);
    let ones = floats(&renderer, &vec![1.0; len]);
    let n_all = scene_set.len();
    let grads = floats(&renderer, &vec![f32::NAN; 23 * n_all]);
    renderer
        .encode_backward(&frame, &ones, &grads)
        .expect("backward");
    let want_grads = read_floats(&renderer, &grads, 23 * n_all);

    // Over the static set's true render the frame is the blended one, bit for bit, and so
    // are its gradients (up to the atomics' order).
    let static_render = floats(&renderer, &static_pixels);
    let frame = renderer
        .encode_frame(scene.clone(), &cam, &settings(), Some(&static_render))
        .expect("frame over the static render");
    assert!(read_floats(&renderer, renderer.frame_pixels(), len) == blended);
    renderer
        .encode_backward(&frame, &ones, &grads)
        .expect("backward");
    assert_same_up_to_tile_order(&read_floats(&renderer, &grads, 23 * n_all), &want_grads);

    // Over a marked render (every value + 1) the marks show which tiles were copied: those
    // where the static set alone draws, and both kinds of tile occur.
    let marked: Vec<f32> = static_pixels.iter().map(|v| v + 1.0).collect();
    let marked = floats(&renderer, &marked);
    renderer
        .encode_frame(scene, &cam, &settings(), Some(&marked))
        .expect("frame over a marked render");
    let got = read_floats(&renderer, renderer.frame_pixels(), len);
    let tiles_x = w.div_ceil(TILE_SIZE);
    let mut copied = vec![None; (tiles_x * h.div_ceil(TILE_SIZE)) as usize];
    for (i, (px, (want, alone))) in got
        .chunks(5)
        .zip(blended.chunks(5).zip(static_pixels.chunks(5)))
        .enumerate()
    {
        let (x, y) = (i as u32 % w, i as u32 / w);
        let is_copy = px.iter().zip(alone).all(|(a, b)| *a == b + 1.0);
        assert!(is_copy || px == want, "pixel ({x}, {y})");
        let tile = &mut copied[(y / TILE_SIZE * tiles_x + x / TILE_SIZE) as usize];
        assert_eq!(*tile.get_or_insert(is_copy), is_copy, "one tile, one way");
    }
    let count = copied.iter().filter(|c| **c == Some(true)).count();
    assert!(
        count > 0 && count < copied.len(),
        "{count} of {} tiles copied",
        copied.len()
    );
}
