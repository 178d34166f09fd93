//! GPU tests of the training session (lavapipe in CI): the SSIM window, Adam against a CPU
//! transcription of torch's update, state round trips, the frozen static set, per-step
//! traffic and the refusals. The losses are checked against torch autograd on the Python
//! side (tests/test_resident_train.py).

use super::{
    ssim_taps, ssim_window, AdamConfig, LossWeights, TrainConfig, TrainSession, TrainedInput,
    ViewTargets, GROUPS, OUTSIDE_SUMS,
};
use crate::camera::Camera;
use crate::gaussians::{GaussianSet, SceneInput};
use crate::raster::{GpuContext, RasterError, RenderSettings, Renderer};
use crate::spacetime::{SpacetimeSet, TimeModel};
use glam::DVec3;

/// The default knobs' rates (lift/trainer.py's learning_rates), in GROUPS' order.
const LEARNING_RATES: [f64; GROUPS] = [1e-3, 5e-3, 1e-3, 5e-2, 1e-2, 5e-4, 1e-2, 1e-3, 1e-2, 5e-3];

fn config() -> TrainConfig {
    TrainConfig {
        adam: AdamConfig {
            learning_rates: LEARNING_RATES,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        },
        losses: LossWeights {
            l1: 0.8,
            ssim: 0.2,
            temporal: 0.0,
            geo: 0.05,
        },
        settings: RenderSettings::default(),
    }
}

/// xorshift floats in [-1, 1).
fn noise(seed: &mut u64, n: usize) -> Vec<f32> {
    (0..n)
        .map(|_| {
            *seed ^= *seed << 13;
            *seed ^= *seed >> 7;
            *seed ^= *seed << 17;
            (*seed >> 40) as f32 / (1u64 << 23) as f32 - 1.0
        })
        .collect()
}

/// `n` Gaussians of SH degree 1 in a cloud 4–8 units in front of a camera looking along +x.
fn cloud(n: usize, seed: u64) -> GaussianSet {
    let mut s = seed;
    let mut set = GaussianSet::with_capacity(1, n);
    let r = noise(&mut s, 16 * n);
    for i in 0..n {
        let v = &r[16 * i..16 * i + 16];
        set.means.push([6.0 + 2.0 * v[0], 1.5 * v[1], 1.5 * v[2]]);
        set.log_scales
            .push([-1.5 + 0.3 * v[3], -1.5 + 0.3 * v[4], -1.5 + 0.3 * v[5]]);
        set.quats.push([v[6], v[7], v[8], v[9]]);
        set.opacity_logits.push(v[10]);
        set.sh.extend([v[11], v[12], v[13]]);
        set.sh.extend(std::iter::repeat_n(0.1 * v[14], 9));
    }
    set
}

fn camera(side: u32) -> Camera {
    Camera::from_fov(
        70.0,
        side,
        side,
        DVec3::ZERO,
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
    )
}

struct Targets {
    rgb: Vec<f32>,
    weight: Vec<f32>,
    depth: Vec<f32>,
}

fn targets(side: u32) -> Targets {
    let pixels = (side * side) as usize;
    let mut seed = 7;
    Targets {
        rgb: noise(&mut seed, 3 * pixels)
            .iter()
            .map(|v| 0.5 + 0.4 * v)
            .collect(),
        weight: vec![1.0; pixels],
        depth: noise(&mut seed, pixels).iter().map(|v| 6.0 + v).collect(),
    }
}

fn unit(set: &GaussianSet) -> Vec<f32> {
    set.means
        .iter()
        .map(|m| (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt().max(1e-3))
        .collect()
}

fn session(
    renderer: &Renderer,
    static_set: &GaussianSet,
    trained: &GaussianSet,
    t: &Targets,
    side: u32,
) -> TrainSession {
    let unit = unit(trained);
    let view = ViewTargets {
        camera: camera(side),
        time: 0.0,
        rgb: &t.rgb,
        weight: &t.weight,
        depth: Some(&t.depth),
        previous: None,
        weight_sum: (side * side) as f32,
        outside: [0.0; OUTSIDE_SUMS],
    };
    TrainSession::new(
        renderer,
        SceneInput::from(static_set),
        fresh(trained, &unit),
        &[view],
        config(),
    )
    .expect("session")
}

/// `n` Gaussians packed as [`TrainSession::state`]'s params (SoA sections of `n`) seen as
/// the sections they are.
fn unpacked(params: &[f32], n: usize) -> SceneInput<'_> {
    SceneInput {
        means: &params[..3 * n],
        log_scales: &params[3 * n..6 * n],
        quats: &params[6 * n..10 * n],
        opacity_logits: &params[10 * n..11 * n],
        sh: &params[11 * n..],
    }
}

/// `trained` with zero moments and statistics, before its first step.
fn fresh<'a>(trained: &'a GaussianSet, unit: &'a [f32]) -> TrainedInput<'a> {
    TrainedInput {
        gaussians: SceneInput::from(trained),
        time: None,
        unit,
        exp_avg: None,
        exp_avg_sq: None,
        grad_accum: None,
        grad_count: None,
        adam_steps: 0,
    }
}

#[test]
fn ssim_window_and_taps_are_kornias() {
    // kornia's docs: get_gaussian_kernel1d(5, 1.5) = [0.1201, 0.2339, 0.2921, 0.2339, 0.1201].
    let taps = ssim_taps(5);
    for (got, want) in taps.iter().zip([0.1201, 0.2339, 0.2921, 0.2339, 0.1201]) {
        assert!((got - want).abs() < 5e-5, "{taps:?}");
    }
    assert!((ssim_taps(11).iter().sum::<f32>() - 1.0).abs() < 1e-6);
    assert_eq!(ssim_window(128, 128), 11);
    assert_eq!(ssim_window(24, 9), 7);
    assert_eq!(ssim_window(7, 40), 5);
}

/// torch's `_single_tensor_adam` for one element (as in adam.wgsl): updates the
/// moments and returns the parameter's step.
fn torch_adam(m: &mut f32, v: &mut f32, g: f32, lr: f64, step: u64) -> f32 {
    let t = step as f64;
    let bias1 = 1.0 - 0.9f64.powf(t);
    let bias2 = 1.0 - 0.999f64.powf(t);
    *m = (0.1f32).mul_add(g - *m, *m);
    *v = (0.001f32 * g).mul_add(g, *v * 0.999f32);
    let denom = v.sqrt() / bias2.sqrt() as f32 + 1e-15f32;
    (-(lr / bias1) as f32 * *m) / denom
}

#[test]
fn adam_matches_a_transcription_of_torch_and_spares_the_static_set() {
    let renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let (static_set, trained) = (cloud(5, 1), cloud(9, 2));
    let side = 16;
    let t = targets(side);
    let mut s = session(&renderer, &static_set, &trained, &t, side);
    let units = unit(&trained);
    let n_all = static_set.len() + trained.len();
    let k = 4;
    let floats = 11 + 3 * k;
    // CPU state: packed trained params and moments.
    let mut params = SceneInput::from(&trained).packed();
    let mut m = vec![0.0f32; params.len()];
    let mut v = vec![0.0f32; params.len()];
    let n = trained.len();
    let group = |i: usize| -> usize {
        // Packed SoA offsets: means 0, log-scales 3n, quats 6n, opacity 10n, SH 11n.
        match i {
            _ if i < 3 * n => 0,
            _ if i < 6 * n => 1,
            _ if i < 10 * n => 2,
            _ if i < 11 * n => 3,
            _ if (i - 11 * n) % (3 * k) < 3 => 4,
            _ => 5,
        }
    };
    let mut seed = 11;
    for step in 1..=3u64 {
        let grads = noise(&mut seed, floats * n_all);
        s.apply_gradients(&grads).expect("adam");
        // The trained part of the gradient sections (sections of n_all, trained after the
        // static set).
        let widths = [3, 3, 4, 1, 3 * k];
        let (mut src, mut dst) = (0, 0);
        for width in widths {
            for j in 0..width * n {
                let i = dst + j;
                let g = grads[src + width * static_set.len() + j];
                let lr = LEARNING_RATES[group(i)];
                if group(i) == 0 {
                    // Adam on the offsets' gradient; the mean moves by unit · Δoffset.
                    let u = units[j / 3];
                    params[i] += torch_adam(&mut m[i], &mut v[i], g * u, lr, step) * u;
                } else {
                    params[i] += torch_adam(&mut m[i], &mut v[i], g, lr, step);
                }
            }
            src += width * n_all;
            dst += width * n;
        }
    }
    let state = s.state().expect("state");
    assert_eq!(state.adam_steps, 3);
    let ulps = |a: f32, b: f32, scale: f32| (a - b).abs() <= 2.0 * f32::EPSILON * scale;
    for (what, got, want) in [
        ("params", &state.params, &params),
        ("exp_avg", &state.exp_avg, &m),
        ("exp_avg_sq", &state.exp_avg_sq, &v),
    ] {
        let scale = want.iter().fold(0.0f32, |a, b| a.max(b.abs()));
        for (i, (a, b)) in got.iter().zip(want.iter()).enumerate() {
            assert!(ulps(*a, *b, scale), "{what}[{i}]: {a} vs {b}");
        }
    }
    let scene = s.scene().expect("scene");
    let whole = {
        let mut all = static_set.clone();
        all.extend_from(&trained);
        SceneInput::from(&all).packed()
    };
    // Context entries of each section are unchanged, bit for bit.
    let widths = [3, 3, 4, 1, 3 * k];
    let mut start = 0;
    for width in widths {
        let c = width * static_set.len();
        assert_eq!(scene[start..start + c], whole[start..start + c]);
        start += width * n_all;
    }
}

#[test]
fn state_round_trips_and_steps_read_nothing_back() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let (static_set, trained) = (cloud(40, 3), cloud(60, 4));
    let side = 32;
    let t = targets(side);
    let mut s = session(&renderer, &static_set, &trained, &t, side);
    let before = s.traffic();
    for _ in 0..5 {
        s.step(&mut renderer, 0).expect("step");
    }
    let after = s.traffic();
    assert_eq!(
        after.read_back, before.read_back,
        "a step reads nothing back"
    );
    assert!(
        after.uploaded - before.uploaded <= 5 * 128,
        "{after:?} after {before:?}"
    );
    let loss = s.loss().expect("loss");
    assert!(
        [
            loss.total,
            loss.l1,
            loss.d_ssim,
            loss.temporal,
            loss.one_minus_pearson,
            loss.covered_weight
        ]
        .iter()
        .all(|v| v.is_finite())
            && loss.total > 0.0,
        "{loss:?}"
    );
    assert!(loss.geo_applied, "L_geo applies: the cloud covers the view");
    let state = s.state().expect("state");
    assert_eq!(state.adam_steps, 5);
    assert_ne!(
        state.params,
        SceneInput::from(&trained).packed(),
        "the steps moved nothing"
    );
    assert!(state.grad_count.contains(&5.0));
    // Write it back and read it again: identical.
    let input = TrainedInput {
        gaussians: unpacked(&state.params, trained.len()),
        time: None,
        unit: &state.unit,
        exp_avg: Some(&state.exp_avg),
        exp_avg_sq: Some(&state.exp_avg_sq),
        grad_accum: Some(&state.grad_accum),
        grad_count: Some(&state.grad_count),
        adam_steps: state.adam_steps,
    };
    s.set_trained(input).expect("set");
    assert_eq!(s.state().expect("state"), state);
}

#[test]
fn bad_inputs_are_refused_with_what_is_wrong() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let (static_set, trained) = (cloud(3, 5), cloud(4, 6));
    let t = targets(16);
    let units = unit(&trained);
    let input = || TrainedInput {
        gaussians: SceneInput::from(&trained),
        time: None,
        unit: &units,
        exp_avg: None,
        exp_avg_sq: None,
        grad_accum: None,
        grad_count: None,
        adam_steps: 0,
    };
    let view = |side: u32, rgb: &'static [f32]| ViewTargets {
        camera: camera(side),
        time: 0.0,
        rgb,
        weight: &[],
        depth: None,
        previous: None,
        weight_sum: 1.0,
        outside: [0.0; OUTSIDE_SUMS],
    };
    let message = |r: Result<TrainSession, RasterError>| match r {
        Err(RasterError::InvalidInput(m)) => m,
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("accepted"),
    };
    let new = |static_set: &GaussianSet, views: &[ViewTargets<'_>]| {
        TrainSession::new(
            &renderer,
            SceneInput::from(static_set),
            input(),
            views,
            config(),
        )
    };
    let good = ViewTargets {
        weight: &t.weight,
        rgb: &t.rgb,
        ..view(16, &[])
    };
    let short = message(new(&static_set, &[view(16, &[0.0; 5])]));
    assert!(short.contains("rgb has 5 values, expected 768"), "{short}");
    // Views may differ in size (a dynamic step's windows), not have non-finite outside sums.
    let small = ViewTargets {
        weight: &t.weight[..64],
        rgb: &t.rgb[..192],
        ..view(8, &[])
    };
    let outside = ViewTargets {
        outside: [f32::NAN; OUTSIDE_SUMS],
        ..view(8, &[])
    };
    let bad_outside = message(new(&static_set, &[good, small, outside]));
    assert!(
        bad_outside.contains("outside sums must be finite"),
        "{bad_outside}"
    );
    let degree0 = GaussianSet {
        sh_degree: 0,
        sh: vec![0.0; 9],
        ..cloud(3, 5)
    };
    let good = ViewTargets {
        weight: &t.weight,
        rgb: &t.rgb,
        ..view(16, &[])
    };
    let degrees = message(new(&degree0, std::slice::from_ref(&good)));
    assert!(degrees.contains("same degree"), "{degrees}");
    let views = [good];
    let mut s = TrainSession::new(
        &renderer,
        SceneInput::from(&static_set),
        input(),
        &views,
        config(),
    )
    .expect("session");
    let v = vec![0.0; 16 * 16 * 5];
    assert!(matches!(
        s.backward_at(&mut renderer, &v),
        Err(RasterError::InvalidInput(m)) if m.contains("render_at first")
    ));
    assert!(matches!(
        s.step(&mut renderer, 1),
        Err(RasterError::InvalidInput(_))
    ));
}

#[test]
fn reserved_frames_do_not_overflow_and_checks_count_overflows() {
    // View 0 looks away from the cloud (almost no intersections), view 1 at it: the
    // renderer's first frame alone would size its buffers for view 0.
    let trained = cloud(400, 5);
    let side = 64;
    let t = targets(side);
    let unit = unit(&trained);
    let away = Camera::from_fov(
        70.0,
        side,
        side,
        DVec3::ZERO,
        DVec3::new(-1.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
    );
    let views: Vec<ViewTargets<'_>> = [away, camera(side)]
        .into_iter()
        .map(|camera| ViewTargets {
            camera,
            time: 0.0,
            rgb: &t.rgb,
            weight: &t.weight,
            depth: None,
            previous: None,
            weight_sum: (side * side) as f32,
            outside: [0.0; OUTSIDE_SUMS],
        })
        .collect();
    let empty = GaussianSet::with_capacity(1, 0);
    let start = |renderer: &Renderer| {
        let input = fresh(&trained, &unit);
        TrainSession::new(renderer, SceneInput::from(&empty), input, &views, config())
            .expect("session")
    };
    let steps = |s: &mut TrainSession, renderer: &mut Renderer| {
        for _ in 0..3 {
            s.step(renderer, 0).expect("step away");
            s.step(renderer, 1).expect("step at the cloud");
        }
        s.check_frames(renderer).expect("check")
    };

    // Without the reservation the first frame at the cloud outgrows the room view 0 left
    // (the check then makes room for the rest).
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let mut s = start(&renderer);
    let check = steps(&mut s, &mut renderer);
    assert!(check.overflowed >= 1, "{check:?}");

    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let mut s = start(&renderer);
    s.reserve_frames(&mut renderer).expect("reserve");
    let check = steps(&mut s, &mut renderer);
    assert_eq!(check.overflowed, 0, "{check:?}");
    assert!(check.max_intersections > 1000, "{check:?}");
    assert!(
        s.state().expect("state").grad_count.contains(&3.0),
        "view 1's steps had gradients"
    );
}

#[test]
fn a_step_over_the_static_sets_own_render_draws_what_the_renderer_draws() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let side = 64;
    let static_set = cloud(300, 11);
    // Four small trained Gaussians at one side of the view: most tiles hold the static set
    // alone, and the steps copy them from the static set's render (made by reserve_frames).
    let mut trained = cloud(4, 12);
    for (mean, scale) in trained.means.iter_mut().zip(&mut trained.log_scales) {
        mean[1] = -1.2 + 0.2 * mean[1];
        *scale = scale.map(|s| s - 1.0);
    }
    let t = targets(side);
    let mut s = session(&renderer, &static_set, &trained, &t, side);
    s.reserve_frames(&mut renderer).expect("reserve");
    let n = trained.len();
    for step in 0..3 {
        // The whole scene as it stands: the static set's sections, each followed by the
        // trained set's.
        let params = s.state().expect("state").params;
        let now = unpacked(&params, n);
        let sections: Vec<Vec<f32>> = SceneInput::from(&static_set)
            .sections()
            .iter()
            .zip(now.sections())
            .map(|(c, t)| [*c, t].concat())
            .collect();
        let scene = SceneInput {
            means: &sections[0],
            log_scales: &sections[1],
            quats: &sections[2],
            opacity_logits: &sections[3],
            sh: &sections[4],
        };
        // Other pixels in the renderer's frame buffer first (the trained set alone), so
        // that a copy that missed a value would leave those.
        renderer
            .forward(
                &SceneInput::from(&trained),
                &camera(side),
                &config().settings,
            )
            .expect("forward");
        s.step(&mut renderer, 0).expect("step");
        let got = s.read_render(&renderer).expect("render");
        let (want, _) = renderer
            .forward(&scene, &camera(side), &config().settings)
            .expect("forward");
        assert!(
            got == want,
            "step {step}: the frame differs from the renderer's"
        );
    }
}

/// `set` with time parameters of `model`: centres across the loop, widths of 1.5–4 frames,
/// colour waves of a tenth and position waves of 2 % of the distance.
fn with_time(set: GaussianSet, model: TimeModel, seed: u64) -> SpacetimeSet {
    let n = set.len();
    let mut s = seed;
    let r = noise(&mut s, model.floats_per_gaussian() * n);
    let (centre, rest) = r.split_at(n);
    let (width, rest) = rest.split_at(n);
    let (colour, position) = rest.split_at(6 * model.colour_harmonics as usize * n);
    SpacetimeSet {
        model,
        canonical: set,
        time_centre: centre.iter().map(|v| (v + 1.0) * 3.0).collect(),
        time_log_width: width.iter().map(|v| (2.75 + 1.25 * v).ln()).collect(),
        colour_terms: colour.iter().map(|v| 0.1 * v).collect(),
        position_terms: position.iter().map(|v| 0.12 * v).collect(),
    }
}

#[test]
fn a_spacetime_set_is_drawn_at_each_views_time_as_the_cpu_form_draws_it() {
    let mut renderer = Renderer::new(GpuContext::new().expect("adapter")).expect("renderer");
    let side = 32;
    let t = targets(side);
    let static_set = cloud(60, 21);
    let model = TimeModel {
        period: 6,
        colour_harmonics: 2,
        position_harmonics: 1,
    };
    let trained = with_time(cloud(40, 22), model, 23);
    let units = unit(&trained.canonical);
    // One camera at two times (the seam's other side included: centres reach 6).
    let views: Vec<ViewTargets<'_>> = [0.5, 5.75]
        .into_iter()
        .map(|time| ViewTargets {
            camera: camera(side),
            time,
            rgb: &t.rgb,
            weight: &t.weight,
            depth: Some(&t.depth),
            previous: None,
            weight_sum: (side * side) as f32,
            outside: [0.0; OUTSIDE_SUMS],
        })
        .collect();
    let input = TrainedInput {
        gaussians: SceneInput::from(&trained.canonical),
        time: Some(trained.time_input()),
        ..fresh(&trained.canonical, &units)
    };
    let mut s = TrainSession::new(
        &renderer,
        SceneInput::from(&static_set),
        input,
        &views,
        config(),
    )
    .expect("session");
    s.reserve_frames(&mut renderer).expect("reserve");
    let n = trained.len();
    let mut frames = Vec::new();
    for view in [0, 1, 1, 0] {
        let params = s.state().expect("state").params;
        let now = SpacetimeSet::from_packed(&params, n, 1, model);
        let mut scene = static_set.clone();
        scene.extend_from(&now.at(views[view].time));
        s.step(&mut renderer, view).expect("step");
        let got = s.read_render(&renderer).expect("render");
        let (want, _) = renderer
            .forward(&SceneInput::from(&scene), &camera(side), &config().settings)
            .expect("forward");
        // The evaluate pass sums the Fourier terms as torch's einsum does, then adds them;
        // the CPU form adds them one by one: the frames differ by float32 rounding only
        // (measured: 3e-6).
        let worst = got
            .iter()
            .zip(&want)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 2e-5, "view {view}: the frames differ by {worst}");
        frames.push(got);
    }
    let moved = frames[0]
        .iter()
        .zip(&frames[1])
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(moved > 0.01, "the two times draw the same frame ({moved})");
    // The state round-trips with its time sections; a set of the other kind is refused.
    let state = s.state().expect("state");
    assert_eq!(
        state.params.len(),
        n * (11 + 12 + model.floats_per_gaussian())
    );
    let now = SpacetimeSet::from_packed(&state.params, n, 1, model);
    let again = TrainedInput {
        gaussians: SceneInput::from(&now.canonical),
        time: Some(now.time_input()),
        unit: &state.unit,
        exp_avg: Some(&state.exp_avg),
        exp_avg_sq: Some(&state.exp_avg_sq),
        grad_accum: Some(&state.grad_accum),
        grad_count: Some(&state.grad_count),
        adam_steps: state.adam_steps,
    };
    s.set_trained(again).expect("set");
    assert_eq!(s.state().expect("state"), state);
    let plain = fresh(&now.canonical, &units);
    assert!(matches!(
        s.set_trained(plain),
        Err(RasterError::InvalidInput(m)) if m.contains("not a set of Gaussians")
    ));
}
