//! A training session: the Gaussians being trained (after a frozen static set), their Adam
//! moments, the stage's targets and the scratch of one step, all resident on the device.
//!
//! One step ([`TrainSession::step`]) is evaluate → forward → losses and their pixel
//! gradient → backward → Adam, submitted without waiting for the host except where the
//! renderer itself waits (docs/rasterizer.md).
//!
//! The parameters Adam updates live apart from what the rasteriser draws: the trained
//! set's parameters in a buffer of their own (SoA sections of the set's length, as its
//! moments), the scene the frames read (the static set, then the trained set's rendered
//! snapshot) in another. The evaluate pass makes the snapshot from the parameters before a
//! forward that follows a change, and its adjoint carries the backward's gradient of the
//! snapshot to the parameters. For a set of Gaussians the snapshot is a copy (one buffer
//! copy a step, per section) and the adjoint the identity: Adam reads the trained part of
//! the scene's gradient as the parameters'. A spacetime set (crate::spacetime: a trained
//! set with time parameters, its time sections after the Gaussians') is drawn at the time of
//! the step's view by a compute pass, whose adjoint writes the time parameters' gradient
//! (spacetime/evaluate.rs, whose pass the viewer also runs); every parameter of its
//! Gaussians still takes the snapshot's gradient as its own.
//!
//! Device memory per trained Gaussian, in floats, with K SH coefficients per channel and T
//! time parameters (2 + 6·(colour + position harmonics): 20 at the default 2 and 1; 0 for a
//! set of Gaussians): the parameters and Adam's two moments 3·(11 + 3K + T), the snapshot
//! 11 + 3K, the gradients of two renders (the step's and the semantic loss's) 2·(11 + 3K),
//! the time parameters' gradient T, the unit and statistics 3. Parameters, moments and
//! snapshot are 116 floats (464 bytes) at SH degree 0 and 296 (1,184 bytes) at degree 3
//! with the default harmonics, 56 and 236 without time; everything, 167 (668 bytes) and 437
//! (1,748 bytes). The largest bindings are the scene's ((11 + 3K)·4 bytes a Gaussian, the
//! static set's included) and the parameters' ((11 + 3K + T)·4: 136 bytes at degree 0, 316
//! at degree 3), each within the device's storage-binding limit: lavapipe's 128 MiB holds
//! the parameters of 986k trained Gaussians of degree 0 with time, 424k of degree 3.
//!
//! The host reads back the loss parts ([`TrainSession::loss`]) when it wants them and the
//! whole trained state ([`TrainSession::state`]) at checkpoints, densification and export;
//! [`Traffic`] counts every byte the session moves between host and device.

use super::adam::{AdamBindings, AdamConfig, AdamKernel, AdamLayout, AdamParams};
use super::losses::{
    LossBuffers, LossKernels, LossParams, LossParts, LossWeights, ViewBuffers, LOSS_PARTS,
    OUTSIDE_SUMS,
};
use crate::camera::Camera;
use crate::gaussians::{sh_coeffs, SceneInput, BASE_FLOATS};
use crate::raster::gpu::{pop_error, read_mapped, submit_checked};
use crate::raster::{
    binding_limit, Frame, GpuScene, IntersectionCheck, RasterError, RenderSettings, Renderer,
    SceneBuffer, PIXEL_CHANNELS,
};
use crate::spacetime::evaluate::{EvaluateKernels, TimeLayout, TimeParams};
use crate::spacetime::{packed_parameters, TimeInput, TimeModel};

/// One view's targets: its camera, rgb (h·w·3), loss weight (h·w), Θ's z-depth (h·w, for
/// L_geo) and the previous timestamp's render (h·w·3, for L_temporal). The camera may be a
/// window of a larger view ([`Camera::window`]): `weight_sum` is then the whole view's and
/// `outside` the loss sums over the rest of it (losses.rs, [`OUTSIDE_SUMS`]). Views may
/// differ in size.
pub struct ViewTargets<'a> {
    pub camera: Camera,
    /// The time the view shows, in frames: a spacetime set is drawn at it (a set of
    /// Gaussians is the same at every time).
    pub time: f64,
    pub rgb: &'a [f32],
    pub weight: &'a [f32],
    pub depth: Option<&'a [f32]>,
    pub previous: Option<&'a [f32]>,
    /// max(Σ weight, 1e-6), as the torch trainer computes it (the caller's float sum).
    pub weight_sum: f32,
    pub outside: [f32; OUTSIDE_SUMS],
}

/// Everything fixed for a session.
#[derive(Clone, Copy, Debug)]
pub struct TrainConfig {
    pub adam: AdamConfig,
    pub losses: LossWeights,
    pub settings: RenderSettings,
}

/// Bytes moved between host and device by the session (the renderer's own per-frame
/// uniforms are not included: see [`TrainSession::traffic`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Traffic {
    pub uploaded: u64,
    pub read_back: u64,
}

/// The trained set with its optimiser state. Parameters and moments are in the packed SoA
/// layout of [`SceneInput::packed`] (means, log-scales, quaternions, opacity logits, SH),
/// a spacetime set's time sections after those ([`TimeInput::sections`]' order); the
/// moments of the means and of the position terms are those of their offsets (see
/// adam.wgsl).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainState {
    pub params: Vec<f32>,
    pub unit: Vec<f32>,
    pub exp_avg: Vec<f32>,
    pub exp_avg_sq: Vec<f32>,
    /// Σ ‖g_offset‖ and the number of steps where it was non-zero, per Gaussian.
    pub grad_accum: Vec<f32>,
    pub grad_count: Vec<f32>,
    /// Adam steps taken (torch's `state["step"]`).
    pub adam_steps: u64,
}

/// What [`TrainSession::set_trained`] uploads; moments and statistics start at zero
/// where they are `None`.
pub struct TrainedInput<'a> {
    /// The Gaussians, or a spacetime set's canonical Gaussians.
    pub gaussians: SceneInput<'a>,
    /// A spacetime set's time parameters (None: a set of Gaussians). A session trains one
    /// kind of set: the one it was made with.
    pub time: Option<TimeInput<'a>>,
    /// Each Gaussian's offset unit (its initial distance from the centre).
    pub unit: &'a [f32],
    pub exp_avg: Option<&'a [f32]>,
    pub exp_avg_sq: Option<&'a [f32]>,
    pub grad_accum: Option<&'a [f32]>,
    pub grad_count: Option<&'a [f32]>,
    pub adam_steps: u64,
}

struct View {
    camera: Camera,
    time: f64,
    params: wgpu::Buffer,
    rgb: wgpu::Buffer,
    weight: wgpu::Buffer,
    depth: Option<wgpu::Buffer>,
    previous: Option<wgpu::Buffer>,
    /// The static set's own render of this view, made by the first
    /// [`TrainSession::reserve_frames`] (the static set and the camera do not change in a
    /// session; views of one camera at several times share it): the steps copy the tiles
    /// that no trained Gaussian reaches from it.
    static_render: Option<wgpu::Buffer>,
}

/// Per-Gaussian buffers of the trained set, sized for its count.
struct Trained {
    len: u32,
    /// The parameters Adam updates, SoA sections of `len` ([`TrainState`]'s layout).
    params: wgpu::Buffer,
    unit: wgpu::Buffer,
    exp_avg: wgpu::Buffer,
    exp_avg_sq: wgpu::Buffer,
    stats: wgpu::Buffer,
    /// A spacetime set's time parameters' gradient (the adjoint's), in their sections.
    time_grads: wgpu::Buffer,
}

/// What a session training a spacetime set has besides.
struct Motion {
    model: TimeModel,
    kernels: EvaluateKernels,
}

pub struct TrainSession {
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: TrainConfig,
    losses: LossKernels,
    adam: AdamKernel,
    loss_buffers: LossBuffers,
    views: Vec<View>,
    /// The largest view's pixel count: the loss buffers' size.
    max_pixels: u32,
    /// Pixels of the last frame rendered (what [`Self::read_render`] reads).
    frame_pixels: u32,
    /// Bound where a view has no depth or previous render.
    placeholder: wgpu::Buffer,
    sh_coeffs: u32,
    n_static: u32,
    /// What the frames draw: the static set, then the trained set's snapshot made by
    /// [`Self::evaluate`]; SoA sections of `capacity`.
    scene: wgpu::Buffer,
    capacity: u32,
    /// Whether the parameters (or the time) changed since the snapshot was made.
    snapshot_stale: bool,
    /// A spacetime set's time model and kernels (None: a set of Gaussians).
    motion: Option<Motion>,
    /// The time the snapshot shows (or, stale, is to show), in frames: the last view's.
    time: f64,
    /// The uniform of the functions of time at `time` (time_layout.wgsl); bound by Adam
    /// for a set of Gaussians too, which does not read it.
    time_params: wgpu::Buffer,
    trained: Trained,
    grads: wgpu::Buffer,
    grads_extra: wgpu::Buffer,
    v_extra: wgpu::Buffer,
    adam_params: wgpu::Buffer,
    adam_steps: u64,
    /// The frame of [`Self::render_at`], for [`Self::backward_at`].
    extra_frame: Option<Frame>,
    has_extra: bool,
    traffic: Traffic,
}

/// Floats per Gaussian in each SoA section, for `k` SH coefficients per channel.
fn section_widths(k: u32) -> [u64; 5] {
    [3, 3, 4, 1, 3 * k as u64]
}

fn invalid(message: String) -> RasterError {
    RasterError::InvalidInput(message)
}

fn storage(device: &wgpu::Device, label: &str, floats: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        // Runtime-sized arrays need at least one element bound.
        size: (4 * floats).max(256).next_multiple_of(16),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

fn check_len(what: &str, got: usize, want: usize) -> Result<(), RasterError> {
    if got != want {
        return Err(invalid(format!("{what} has {got} values, expected {want}")));
    }
    Ok(())
}

impl TrainSession {
    /// A session on `renderer`'s device: uploads the frozen `static_set` (may be empty), the
    /// trained set and the views' targets once.
    pub fn new(
        renderer: &Renderer,
        static_set: SceneInput<'_>,
        trained: TrainedInput<'_>,
        views: &[ViewTargets<'_>],
        config: TrainConfig,
    ) -> Result<Self, RasterError> {
        let ctx = renderer.context();
        let device = ctx.device.clone();
        let queue = ctx.queue.clone();
        if views.is_empty() {
            return Err(invalid("no views to train on".into()));
        }
        let max_pixels = views
            .iter()
            .map(|v| v.camera.width * v.camera.height)
            .max()
            .unwrap_or(0);
        let (n_static, k_static) = static_set.validate().map_err(invalid)?;
        let (n_train, k_train) = trained.gaussians.validate().map_err(invalid)?;
        let sh_coeffs = if n_train > 0 { k_train } else { k_static };
        if n_static > 0 && n_train > 0 && k_static != k_train {
            return Err(invalid(format!(
                "the static set has {k_static} SH coefficients per channel and the trained set \
                 {k_train}: give both the same degree"
            )));
        }
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let loss_buffers = LossBuffers::new(&device, max_pixels);
        let uniform = |label: &str, size: usize| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let adam_params = uniform("adam params", std::mem::size_of::<AdamParams>());
        let time_params = uniform("time params", std::mem::size_of::<TimeParams>());
        let motion = trained.time.map(|t| Motion {
            model: t.model,
            kernels: EvaluateKernels::new(&device),
        });
        let mut session = Self {
            losses: LossKernels::new(&device),
            adam: AdamKernel::new(&device),
            loss_buffers,
            views: Vec::with_capacity(views.len()),
            max_pixels,
            frame_pixels: 0,
            placeholder: storage(&device, "placeholder", 1),
            sh_coeffs,
            n_static,
            scene: storage(&device, "scene", 0),
            capacity: 0,
            snapshot_stale: true,
            motion,
            time: 0.0,
            time_params,
            trained: Trained {
                len: 0,
                params: storage(&device, "trained parameters", 0),
                unit: storage(&device, "unit", 0),
                exp_avg: storage(&device, "exp_avg", 0),
                exp_avg_sq: storage(&device, "exp_avg_sq", 0),
                stats: storage(&device, "gradient statistics", 0),
                time_grads: storage(&device, "time gradients", 0),
            },
            grads: storage(&device, "gradients", 0),
            grads_extra: storage(&device, "extra gradients", 0),
            v_extra: storage(&device, "extra pixel gradients", 0),
            adam_params,
            adam_steps: 0,
            extra_frame: None,
            has_extra: false,
            traffic: Traffic::default(),
            config,
            device,
            queue,
        };
        for view in views {
            session.add_view(view)?;
        }
        session.v_extra = storage(
            &session.device,
            "extra pixel gradients",
            PIXEL_CHANNELS as u64 * max_pixels as u64,
        );
        session.allocate_scene(n_static + n_train)?;
        session.write_scene(0, &static_set);
        session.set_trained(trained)?;
        pop_error(scope)?;
        Ok(session)
    }

    fn add_view(&mut self, view: &ViewTargets<'_>) -> Result<(), RasterError> {
        let (w, h) = (view.camera.width, view.camera.height);
        if w.min(h) < 4 {
            return Err(invalid(format!(
                "views must be at least 4 pixels a side for SSIM, got {w}x{h}"
            )));
        }
        if !view.time.is_finite() {
            return Err(invalid(format!(
                "a view's time must be finite, got {}",
                view.time
            )));
        }
        if !view.outside.iter().all(|v| v.is_finite()) {
            return Err(invalid(format!(
                "a view's outside sums must be finite, got {:?}",
                view.outside
            )));
        }
        let pixels = (w * h) as usize;
        check_len("a view's rgb", view.rgb.len(), 3 * pixels)?;
        check_len("a view's weight", view.weight.len(), pixels)?;
        if let Some(depth) = view.depth {
            check_len("a view's depth", depth.len(), pixels)?;
        }
        if let Some(previous) = view.previous {
            check_len("a view's previous render", previous.len(), 3 * pixels)?;
        }
        if !(view.weight_sum.is_finite() && view.weight_sum > 0.0) {
            return Err(invalid(format!(
                "a view's weight sum must be finite and > 0, got {}",
                view.weight_sum
            )));
        }
        let params = LossParams::new(
            w,
            h,
            view.weight_sum,
            self.config.losses,
            view.previous.is_some(),
            view.depth.is_some(),
            view.outside,
        );
        let uniform = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("loss params"),
            size: std::mem::size_of::<LossParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.upload(&uniform, 0, bytemuck::bytes_of(&params));
        let mut array = |label: &str, data: &[f32]| {
            let buffer = storage(&self.device, label, data.len() as u64);
            self.upload(&buffer, 0, bytemuck::cast_slice(data));
            buffer
        };
        let view = View {
            camera: view.camera,
            time: view.time,
            params: uniform,
            rgb: array("target rgb", view.rgb),
            weight: array("target weight", view.weight),
            depth: view.depth.map(|d| array("target depth", d)),
            previous: view.previous.map(|p| array("previous render", p)),
            static_render: None,
        };
        self.views.push(view);
        Ok(())
    }

    /// What the session was configured with.
    pub fn config(&self) -> TrainConfig {
        self.config
    }

    /// Host↔device bytes the session has moved so far, the frame checks of
    /// [`Self::check_frames`] included. The renderer's own upload of its per-frame
    /// parameters comes on top (its size is counted by the benchmark).
    pub fn traffic(&self) -> Traffic {
        self.traffic
    }

    pub fn len(&self) -> usize {
        self.trained.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.trained.len == 0
    }

    pub fn static_len(&self) -> usize {
        self.n_static as usize
    }

    /// The SH degree of every Gaussian in the session.
    pub fn sh_degree(&self) -> u32 {
        (0..=3)
            .find(|&d| sh_coeffs(d) == self.sh_coeffs as usize)
            .expect("validated SH coefficients")
    }

    pub fn views(&self) -> usize {
        self.views.len()
    }

    /// Adam steps taken so far.
    pub fn adam_steps(&self) -> u64 {
        self.adam_steps
    }

    fn upload(&mut self, buffer: &wgpu::Buffer, offset: u64, bytes: &[u8]) {
        if !bytes.is_empty() {
            self.queue.write_buffer(buffer, offset, bytes);
            self.traffic.uploaded += bytes.len() as u64;
        }
    }

    /// Copies `(buffer, byte offset, bytes)` regions to the host, one after the other,
    /// in one round trip.
    fn read(&mut self, regions: &[(&wgpu::Buffer, u64, u64)]) -> Result<Vec<f32>, RasterError> {
        let total: u64 = regions.iter().map(|r| r.2).sum();
        if total == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("train read-back"),
            size: total,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        let mut at = 0;
        for &(buffer, offset, bytes) in regions {
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(buffer, offset, &staging, at, bytes);
            }
            at += bytes;
        }
        self.submit(encoder)?;
        let data = bytemuck::pod_collect_to_vec(&read_mapped(&self.device, &staging, total)?);
        self.traffic.read_back += total;
        Ok(data)
    }

    /// Makes room for `total` Gaussians (static set + trained); a larger scene buffer gets the
    /// static set copied over on the device (the snapshot is made again by the next
    /// [`Self::evaluate`]).
    fn allocate_scene(&mut self, total: u32) -> Result<(), RasterError> {
        if total <= self.capacity && self.capacity > 0 {
            return Ok(());
        }
        let bytes = GpuScene::bytes_for(total as usize, self.sh_coeffs as usize);
        let allowed = binding_limit(&self.device);
        if bytes > allowed {
            return Err(RasterError::TooLarge {
                gaussians: total as usize,
                bytes,
                allowed,
            });
        }
        let scene = storage(&self.device, "scene", bytes / 4);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        let (mut old_start, mut new_start) = (0, 0);
        for width in section_widths(self.sh_coeffs) {
            let bytes = 4 * width * self.n_static as u64;
            if bytes > 0 && self.capacity > 0 {
                encoder.copy_buffer_to_buffer(&self.scene, old_start, &scene, new_start, bytes);
            }
            old_start += 4 * width * self.capacity as u64;
            new_start += 4 * width * total as u64;
        }
        self.queue.submit([encoder.finish()]);
        self.scene = scene;
        self.capacity = total;
        Ok(())
    }

    /// Writes `part` as scene Gaussians `first..first + part.len()`.
    fn write_scene(&mut self, first: u32, part: &SceneInput<'_>) {
        let scene = self.scene.clone();
        let mut start = 0;
        for (data, width) in part
            .sections()
            .into_iter()
            .zip(section_widths(self.sh_coeffs))
        {
            self.upload(
                &scene,
                4 * (start + width * first as u64),
                bytemuck::cast_slice(data),
            );
            start += width * self.capacity as u64;
        }
    }

    /// Floats per Gaussian of the scene and its gradient.
    fn floats_per_gaussian(&self) -> u64 {
        BASE_FLOATS as u64 + 3 * self.sh_coeffs as u64
    }

    /// Time parameters per trained Gaussian (0 for a set of Gaussians).
    fn time_floats(&self) -> u64 {
        self.motion
            .as_ref()
            .map_or(0, |m| m.model.floats_per_gaussian() as u64)
    }

    /// Floats per trained Gaussian of its parameters and of each of its moments.
    fn param_floats(&self) -> u64 {
        self.floats_per_gaussian() + self.time_floats()
    }

    /// The evaluate pass and its adjoint, of a session that trains a spacetime set.
    fn kernels(&self) -> &EvaluateKernels {
        &self
            .motion
            .as_ref()
            .expect("a spacetime set's session")
            .kernels
    }

    /// The time model of the spacetime set the session trains (None: a set of Gaussians).
    pub fn time_model(&self) -> Option<TimeModel> {
        self.motion.as_ref().map(|m| m.model)
    }

    /// Replaces the trained set (after densification, or to resume): parameters, units,
    /// moments, statistics and the Adam step count. A set of the session's kind: a
    /// spacetime set of its time model, or a set of Gaussians.
    pub fn set_trained(&mut self, t: TrainedInput<'_>) -> Result<(), RasterError> {
        let (n, k) = t.gaussians.validate().map_err(invalid)?;
        if n > 0 && k != self.sh_coeffs {
            return Err(invalid(format!(
                "{k} SH coefficients per channel for a session of {}",
                self.sh_coeffs
            )));
        }
        let nn = n as usize;
        let model = t.time.map(|time| time.model);
        if model != self.time_model() {
            let kind = |m: Option<TimeModel>| match m {
                Some(m) => format!("a spacetime set of {m:?}"),
                None => "a set of Gaussians".to_string(),
            };
            return Err(invalid(format!(
                "this session trains {}, not {}",
                kind(self.time_model()),
                kind(model)
            )));
        }
        if let Some(time) = t.time {
            time.check(nn).map_err(invalid)?;
        }
        let floats = self.param_floats() as usize * nn;
        check_len("unit", t.unit.len(), nn)?;
        if !t.unit.iter().all(|u| u.is_finite() && *u > 0.0) {
            return Err(invalid("unit must be finite and > 0".into()));
        }
        for (what, data, want) in [
            ("exp_avg", t.exp_avg, floats),
            ("exp_avg_sq", t.exp_avg_sq, floats),
            ("grad_accum", t.grad_accum, nn),
            ("grad_count", t.grad_count, nn),
        ] {
            if let Some(d) = data {
                check_len(what, d.len(), want)?;
            }
        }
        self.allocate_scene(self.n_static + n)?;
        // A spacetime set's parameters may outgrow the scene's binding (a small static set).
        let (bytes, allowed) = (4 * floats as u64, binding_limit(&self.device));
        if bytes > allowed {
            return Err(RasterError::TooLarge {
                gaussians: nn,
                bytes,
                allowed,
            });
        }
        let device = self.device.clone();
        let fresh = |label: &str, len: usize, data: Option<&[f32]>, s: &mut Self| {
            let buffer = storage(&device, label, len as u64);
            if let Some(d) = data {
                s.upload(&buffer, 0, bytemuck::cast_slice(d));
            }
            buffer
        };
        let packed = packed_parameters(&t.gaussians, t.time);
        let params = fresh("trained parameters", floats, Some(&packed), self);
        let unit = fresh("unit", nn, Some(t.unit), self);
        let exp_avg = fresh("exp_avg", floats, t.exp_avg, self);
        let exp_avg_sq = fresh("exp_avg_sq", floats, t.exp_avg_sq, self);
        let stats = fresh("gradient statistics", 2 * nn, None, self);
        if let Some(accum) = t.grad_accum {
            self.upload(&stats, 0, bytemuck::cast_slice(accum));
        }
        if let Some(count) = t.grad_count {
            self.upload(&stats, 4 * n as u64, bytemuck::cast_slice(count));
        }
        let time_grads = fresh(
            "time gradients",
            self.time_floats() as usize * nn,
            None,
            self,
        );
        self.trained = Trained {
            len: n,
            params,
            unit,
            exp_avg,
            exp_avg_sq,
            stats,
            time_grads,
        };
        let grad_floats = self.floats_per_gaussian() * (self.n_static + n) as u64;
        self.grads = storage(&device, "gradients", grad_floats);
        self.grads_extra = storage(&device, "extra gradients", grad_floats);
        self.adam_steps = t.adam_steps;
        self.snapshot_stale = true;
        self.extra_frame = None;
        self.has_extra = false;
        Ok(())
    }

    fn scene_buffer(&self) -> SceneBuffer {
        SceneBuffer {
            buffer: self.scene.clone(),
            len: self.n_static + self.trained.len,
            stride: self.capacity,
            sh_coeffs: self.sh_coeffs,
            n_static: self.n_static,
        }
    }

    /// The time the next forward draws the trained set at: a spacetime set's snapshot is
    /// made again when it changes.
    fn set_time(&mut self, time: f64) {
        if self.motion.is_some() && time != self.time {
            self.time = time;
            self.snapshot_stale = true;
        }
    }

    /// Writes the uniform of the functions of time at the session's time.
    fn write_time_params(&mut self, model: TimeModel) {
        let layout = TimeLayout {
            n_static: self.n_static,
            n_train: self.trained.len,
            scene_len: self.capacity,
            sh_coeffs: self.sh_coeffs,
            has_extra: self.has_extra,
        };
        let uniform = self.time_params.clone();
        let params = TimeParams::new(&model, self.time, layout);
        self.upload(&uniform, 0, bytemuck::bytes_of(&params));
    }

    /// The evaluate pass: makes the scene's snapshot of the trained set from its parameters
    /// where they (or the time) changed since the last one: a copy of each SoA section, or
    /// a spacetime set drawn at the session's time (evaluate.wgsl). Every forward that
    /// draws the trained set runs it first.
    fn evaluate(&mut self) -> Result<(), RasterError> {
        if !self.snapshot_stale {
            return Ok(());
        }
        if let Some(model) = self.time_model() {
            self.write_time_params(model);
            let mut encoder = self.device.create_command_encoder(&Default::default());
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                self.kernels().encode_evaluate(
                    &self.device,
                    &mut pass,
                    &self.time_params,
                    &self.trained.params,
                    &self.scene,
                    self.trained.len,
                );
            }
            self.submit(encoder)?;
            self.snapshot_stale = false;
            return Ok(());
        }
        let mut encoder = self.device.create_command_encoder(&Default::default());
        let (n, mut params_at, mut scene_at) = (self.trained.len as u64, 0, 0);
        for width in section_widths(self.sh_coeffs) {
            let bytes = 4 * width * n;
            if bytes > 0 {
                let to = scene_at + 4 * width * self.n_static as u64;
                encoder.copy_buffer_to_buffer(
                    &self.trained.params,
                    params_at,
                    &self.scene,
                    to,
                    bytes,
                );
            }
            params_at += bytes;
            scene_at += 4 * width * self.capacity as u64;
        }
        self.submit(encoder)?;
        self.snapshot_stale = false;
        Ok(())
    }

    fn submit(&self, encoder: wgpu::CommandEncoder) -> Result<(), RasterError> {
        submit_checked(&self.device, &self.queue, encoder)
    }

    fn view(&self, view: usize) -> Result<&View, RasterError> {
        let count = self.views.len();
        self.views
            .get(view)
            .ok_or_else(|| invalid(format!("view {view} out of range ({count} views)")))
    }

    /// Submits the loss passes of view `view` on the forward output `pixels`.
    fn encode_losses(&self, view: usize, pixels: &wgpu::Buffer) -> Result<(), RasterError> {
        let v = self.view(view)?;
        let view_buffers = ViewBuffers {
            width: v.camera.width,
            height: v.camera.height,
            params: &v.params,
            rgb: &v.rgb,
            weight: &v.weight,
            depth: v.depth.as_ref().unwrap_or(&self.placeholder),
            previous: v.previous.as_ref().unwrap_or(&self.placeholder),
        };
        let mut encoder = self.device.create_command_encoder(&Default::default());
        self.losses.encode(
            &self.device,
            &mut encoder,
            &self.loss_buffers,
            &view_buffers,
            pixels,
        );
        self.submit(encoder)
    }

    /// Sizes the renderer's intersection buffers for every view of the current scene:
    /// encodes each view's forward and reads the largest count once (one wait). Call it
    /// where the loop waits anyway (at the start of a stage, after densification): steps
    /// do not wait for their counts, and a frame with more intersections than room draws
    /// only the background (docs/rasterizer.md, "Frames without a wait"). The first call
    /// also renders the static set alone from each view, which the steps then copy where no
    /// trained Gaussian reaches (without it, they blend every tile).
    pub fn reserve_frames(&mut self, renderer: &mut Renderer) -> Result<(), RasterError> {
        // One frame per camera, at the first time it is seen: a camera's frames at other
        // times draw the same Gaussians but for their opacities and small moves, and a
        // frame that outgrows the room still grows it (`check_frames`). A spacetime stage
        // sees each camera at every timestamp: one frame a camera, not one a timestamp.
        for index in 0..self.views.len() {
            let View { camera, time, .. } = self.views[index];
            if self.views[..index].iter().any(|seen| seen.camera == camera) {
                continue;
            }
            self.set_time(time);
            self.evaluate()?;
            renderer.encode_frame(self.scene_buffer(), &camera, &self.config.settings, None)?;
        }
        self.extra_frame = None;
        self.check_frames(renderer)?;
        // With room for the whole scene's frames, the static set's own ones fit too.
        self.render_static(renderer)
    }

    /// The renderer's check of the frames since the last one (16 bytes read back): how
    /// many overflowed their intersection buffers (their step had no gradient but Adam's
    /// moments still moved the parameters) and the room from now on, grown when the
    /// largest frame came near it. Call it with the loss read-back.
    pub fn check_frames(
        &mut self,
        renderer: &mut Renderer,
    ) -> Result<IntersectionCheck, RasterError> {
        let check = renderer.check_intersections()?;
        self.traffic.read_back += std::mem::size_of::<[u32; 4]>() as u64;
        Ok(check)
    }

    /// One training step on view `view`: forward, losses, backward, Adam.
    pub fn step(&mut self, renderer: &mut Renderer, view: usize) -> Result<(), RasterError> {
        self.forward_backward(renderer, view)?;
        self.apply_adam()
    }

    /// The first half of a step: forward of view `view`, the losses and their pixel
    /// gradient, backward into the gradient buffer. [`Self::apply_adam`] completes it
    /// (with [`Self::render_at`] / [`Self::backward_at`] in between to add a second
    /// render's gradient, as the semantic loss does).
    pub fn forward_backward(
        &mut self,
        renderer: &mut Renderer,
        view: usize,
    ) -> Result<(), RasterError> {
        let v = self.view(view)?;
        let (camera, time, static_render) = (v.camera, v.time, v.static_render.clone());
        self.set_time(time);
        self.evaluate()?;
        let frame = renderer.encode_frame(
            self.scene_buffer(),
            &camera,
            &self.config.settings,
            static_render.as_ref(),
        )?;
        self.frame_pixels = camera.width * camera.height;
        self.encode_losses(view, renderer.frame_pixels())?;
        renderer.encode_backward(&frame, &self.loss_buffers.v_pixels, &self.grads)?;
        self.extra_frame = None;
        self.has_extra = false;
        Ok(())
    }

    /// Renders the static set alone from every view that has no such render yet, and keeps
    /// it (the static set and the views do not change in a session).
    fn render_static(&mut self, renderer: &mut Renderer) -> Result<(), RasterError> {
        if self.n_static == 0 {
            return Ok(());
        }
        let static_set = SceneBuffer {
            len: self.n_static,
            ..self.scene_buffer()
        };
        for index in 0..self.views.len() {
            if self.views[index].static_render.is_some() {
                continue;
            }
            let camera = self.views[index].camera;
            // The same camera at another time shares its render.
            let shared = self.views[..index]
                .iter()
                .find(|seen| seen.camera == camera)
                .and_then(|seen| seen.static_render.clone());
            if shared.is_some() {
                self.views[index].static_render = shared;
                continue;
            }
            renderer.encode_frame(static_set.clone(), &camera, &self.config.settings, None)?;
            let floats = PIXEL_CHANNELS as u64 * (camera.width * camera.height) as u64;
            let kept = storage(&self.device, "static render", floats);
            let mut encoder = self.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(renderer.frame_pixels(), 0, &kept, 0, 4 * floats);
            self.submit(encoder)?;
            self.views[index].static_render = Some(kept);
        }
        Ok(())
    }

    /// The losses of view `view` on given forward pixels (H·W·5) instead of a render:
    /// returns the pixel gradient and the loss parts (for checking the loss kernels
    /// against torch on chosen inputs).
    pub fn loss_gradient(
        &mut self,
        view: usize,
        pixels: &[f32],
    ) -> Result<(Vec<f32>, LossParts), RasterError> {
        let camera = self.view(view)?.camera;
        let len = PIXEL_CHANNELS * (camera.width * camera.height) as usize;
        check_len("pixels", pixels.len(), len)?;
        let input = storage(&self.device, "given pixels", len as u64);
        self.upload(&input, 0, bytemuck::cast_slice(pixels));
        self.encode_losses(view, &input)?;
        let v_pixels = self.loss_buffers.v_pixels.clone();
        let gradient = self.read(&[(&v_pixels, 0, 4 * len as u64)])?;
        Ok((gradient, self.loss()?))
    }

    /// The pixels (H·W·5) of the last forward.
    pub fn read_render(&mut self, renderer: &Renderer) -> Result<Vec<f32>, RasterError> {
        let bytes = 4 * PIXEL_CHANNELS as u64 * self.frame_pixels as u64;
        self.read(&[(renderer.frame_pixels(), 0, bytes)])
    }

    /// Renders the current scene at `camera` (at most the largest view's pixels) and reads the pixels
    /// back; [`Self::backward_at`] then adds the gradient of a loss on them.
    pub fn render_at(
        &mut self,
        renderer: &mut Renderer,
        camera: &Camera,
    ) -> Result<Vec<f32>, RasterError> {
        if camera.width * camera.height > self.max_pixels {
            return Err(invalid(format!(
                "the camera may have at most the largest view's {} pixels, got {}x{}",
                self.max_pixels, camera.width, camera.height
            )));
        }
        self.evaluate()?;
        let frame =
            renderer.encode_frame(self.scene_buffer(), camera, &self.config.settings, None)?;
        self.frame_pixels = camera.width * camera.height;
        self.extra_frame = Some(frame);
        self.read_render(renderer)
    }

    /// Backward of [`Self::render_at`]'s frame for the pixel gradient `v_pixels` (H·W·5);
    /// the next [`Self::apply_adam`] adds these gradients to the step's.
    pub fn backward_at(
        &mut self,
        renderer: &mut Renderer,
        v_pixels: &[f32],
    ) -> Result<(), RasterError> {
        let frame = self
            .extra_frame
            .take()
            .ok_or_else(|| invalid("backward_at needs a render_at first".into()))?;
        let (width, height) = frame.size();
        check_len(
            "v_pixels",
            v_pixels.len(),
            PIXEL_CHANNELS * (width * height) as usize,
        )?;
        let v_extra = self.v_extra.clone();
        self.upload(&v_extra, 0, bytemuck::cast_slice(v_pixels));
        renderer.encode_backward(&frame, &v_extra, &self.grads_extra)?;
        self.has_extra = true;
        Ok(())
    }

    /// One Adam step with the gradients in the gradient buffer (plus the extra ones after
    /// a [`Self::backward_at`]).
    pub fn apply_adam(&mut self) -> Result<(), RasterError> {
        self.adam_steps += 1;
        let layout = AdamLayout {
            n_static: self.n_static,
            n_train: self.trained.len,
            sh_coeffs: self.sh_coeffs,
            has_extra: self.has_extra,
            timed: self.motion.is_some(),
        };
        let params = self.config.adam.params(self.adam_steps, layout);
        let uniform = self.adam_params.clone();
        self.upload(&uniform, 0, bytemuck::bytes_of(&params));
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            self.encode_adjoint(&mut pass);
            let bindings = AdamBindings {
                params: &self.adam_params,
                trained: &self.trained.params,
                grads: &self.grads,
                grads_extra: &self.grads_extra,
                exp_avg: &self.trained.exp_avg,
                exp_avg_sq: &self.trained.exp_avg_sq,
                unit: &self.trained.unit,
                stats: &self.trained.stats,
                time_grads: &self.trained.time_grads,
                time_params: &self.time_params,
            };
            self.adam
                .encode(&self.device, &mut pass, &bindings, self.trained.len);
        }
        self.has_extra = false;
        self.snapshot_stale = true;
        self.submit(encoder)
    }

    /// Writes the uniform of a spacetime set's functions of time (with whether this step has
    /// a second render's gradients) and encodes the adjoint of its evaluate pass: the time
    /// parameters' gradient from the scene's. Nothing for a set of Gaussians.
    fn encode_adjoint(&mut self, pass: &mut wgpu::ComputePass<'_>) {
        let Some(model) = self.time_model() else {
            return;
        };
        self.write_time_params(model);
        self.kernels().encode_adjoint(
            &self.device,
            pass,
            &self.time_params,
            &self.trained.params,
            &self.grads,
            &self.grads_extra,
            &self.trained.time_grads,
            self.trained.len,
        );
    }

    /// The trained parameters' gradient, in [`TrainState`]'s layout (of the means and the
    /// position terms themselves, not of their offsets), through the evaluate pass's adjoint
    /// at the session's time: of the last backward (with [`Self::backward_at`]'s), or of
    /// `scene_gradient` (the static set + trained scene, in the backward's layout), which
    /// replaces it. For checking the adjoint and a step's gradient against torch's.
    pub fn parameter_gradient(
        &mut self,
        scene_gradient: Option<&[f32]>,
    ) -> Result<Vec<f32>, RasterError> {
        let (n_static, n) = (self.n_static as u64, self.trained.len as u64);
        if let Some(grads) = scene_gradient {
            let floats = self.floats_per_gaussian() * (n_static + n);
            check_len("gradients", grads.len(), floats as usize)?;
            let buffer = self.grads.clone();
            self.upload(&buffer, 0, bytemuck::cast_slice(grads));
            self.has_extra = false;
        }
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            self.encode_adjoint(&mut pass);
        }
        self.submit(encoder)?;
        // The trained part of each gradient section, of the step's render and of the second
        // one where there is one, then the time sections.
        let renders: &[&wgpu::Buffer] = if self.has_extra {
            &[&self.grads, &self.grads_extra]
        } else {
            &[&self.grads]
        };
        let mut regions = Vec::new();
        for buffer in renders {
            let mut at = 0;
            for width in section_widths(self.sh_coeffs) {
                regions.push((
                    (*buffer).clone(),
                    4 * (at + width * n_static),
                    4 * width * n,
                ));
                at += width * (n_static + n);
            }
        }
        let base = (self.floats_per_gaussian() * n) as usize;
        let time_grads = self.trained.time_grads.clone();
        regions.push((time_grads, 0, 4 * self.time_floats() * n));
        let borrowed: Vec<(&wgpu::Buffer, u64, u64)> =
            regions.iter().map(|(b, o, s)| (b, *o, *s)).collect();
        let flat = self.read(&borrowed)?;
        let (step, rest) = flat.split_at(base);
        let (extra, time) = rest.split_at(rest.len() - (self.time_floats() * n) as usize);
        let mut gradient = step.to_vec();
        for (g, e) in gradient.iter_mut().zip(extra) {
            *g += e;
        }
        gradient.extend_from_slice(time);
        Ok(gradient)
    }

    /// Adam on given gradients (for the static set + trained scene, in the backward's
    /// layout): what a step does after its backward, for checking the optimiser alone.
    pub fn apply_gradients(&mut self, grads: &[f32]) -> Result<(), RasterError> {
        let floats =
            self.floats_per_gaussian() as usize * (self.n_static + self.trained.len) as usize;
        check_len("gradients", grads.len(), floats)?;
        let buffer = self.grads.clone();
        self.upload(&buffer, 0, bytemuck::cast_slice(grads));
        self.has_extra = false;
        self.apply_adam()
    }

    /// The last step's loss and its parts.
    pub fn loss(&mut self) -> Result<LossParts, RasterError> {
        let loss = self.loss_buffers.loss.clone();
        let parts = self.read(&[(&loss, 0, 4 * LOSS_PARTS as u64)])?;
        Ok(LossParts::from_floats(
            parts.try_into().expect("LOSS_PARTS floats"),
        ))
    }

    /// The whole scene, static set then trained set (its parameters), packed as
    /// [`SceneInput::packed`]: each section's static part, then its trained part.
    pub fn scene(&mut self) -> Result<Vec<f32>, RasterError> {
        let (n_static, n) = (self.n_static as u64, self.trained.len as u64);
        let mut regions = Vec::new();
        let (mut scene_at, mut params_at) = (0, 0);
        for width in section_widths(self.sh_coeffs) {
            regions.push((self.scene.clone(), scene_at, 4 * width * n_static));
            regions.push((self.trained.params.clone(), params_at, 4 * width * n));
            scene_at += 4 * width * self.capacity as u64;
            params_at += 4 * width * n;
        }
        let borrowed: Vec<(&wgpu::Buffer, u64, u64)> =
            regions.iter().map(|(b, o, s)| (b, *o, *s)).collect();
        self.read(&borrowed)
    }

    /// The trained set's parameters, in [`TrainState`]'s layout.
    pub fn params(&mut self) -> Result<Vec<f32>, RasterError> {
        let params = self.trained.params.clone();
        let bytes = 4 * self.param_floats() * self.trained.len as u64;
        self.read(&[(&params, 0, bytes)])
    }

    /// Reads the trained set and its optimiser state back (one round trip).
    pub fn state(&mut self) -> Result<TrainState, RasterError> {
        let n = self.trained.len as u64;
        let floats = self.param_floats() * n;
        let t = &self.trained;
        let mut regions = Vec::new();
        for (buffer, len) in [
            (&t.params, floats),
            (&t.unit, n),
            (&t.exp_avg, floats),
            (&t.exp_avg_sq, floats),
            (&t.stats, 2 * n),
        ] {
            regions.push((buffer.clone(), 0, 4 * len));
        }
        let borrowed: Vec<(&wgpu::Buffer, u64, u64)> =
            regions.iter().map(|(b, o, s)| (b, *o, *s)).collect();
        let flat = self.read(&borrowed)?;
        let (n, floats) = (n as usize, floats as usize);
        let mut rest = flat.as_slice();
        let mut take = |len: usize| {
            let (head, tail) = rest.split_at(len);
            rest = tail;
            head.to_vec()
        };
        Ok(TrainState {
            params: take(floats),
            unit: take(n),
            exp_avg: take(floats),
            exp_avg_sq: take(floats),
            grad_accum: take(n),
            grad_count: take(n),
            adam_steps: self.adam_steps,
        })
    }
}
