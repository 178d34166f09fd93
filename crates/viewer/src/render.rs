//! The viewer's frame render path: the Gaussians of the shown timestamp, resident on the
//! GPU, drawn by splat-core's forward rasteriser (the same kernels as training and
//! `pano4d render`) into an 8-bit RGBA texture that egui shows as it is.
//!
//! Dynamic sets reach the GPU in one of two ways ([`crate::residency`]): every timestamp's
//! set stored on the GPU when the scene is loaded, and copied on the GPU into the slot
//! after the static set when its timestamp is shown (the draw is then the still frame's
//! draw); or, when they do not fit, decoded and uploaded into that slot as they are shown.
//! A version-2 scene's one spacetime set is uploaded once and evaluated into that slot by a
//! compute pass (splat-core's, the trainer's own) whenever the shown time changes, at any
//! real time: the draw is the still frame's draw after one pass over the dynamic Gaussians.
//!
//! The same [`FrameRenderer`] runs on the device egui created (the window and the UI
//! tests) and on a device of its own (headless rendering and the benchmark).

use std::path::Path;
use std::time::{Duration, Instant};

use image::RgbaImage;
use splat_core::camera::Camera;
use splat_core::gaussians::{sh_coeffs, GaussianSet, SceneInput};
use splat_core::raster::{
    target_texture, AdapterSummary, GpuContext, GpuScene, RasterError, RenderSettings, Renderer,
    StoredSet,
};
use splat_core::spacetime::{GpuSpacetimeSet, TimeModel};

use crate::residency::{self, Playback};
use crate::scene::Scene;

/// How a frame is drawn, besides the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameOptions {
    /// Linear 0..1 RGB behind the Gaussians.
    pub background: [f32; 3],
    /// Multiplies every Gaussian's scale (1 = as trained).
    pub splat_scale: f32,
}

impl Default for FrameOptions {
    fn default() -> Self {
        Self {
            background: [0.0; 3],
            splat_scale: 1.0,
        }
    }
}

/// Why a scene does not fit, with the advice to use the draft preset. `allowed` is the
/// device's buffer limit when that is the reason, `None` when an allocation failed.
fn too_large_message(count: usize, need: u64, allowed: Option<u64>, adapter: &str) -> String {
    const MIB: u64 = 1 << 20;
    let reason = match allowed {
        Some(limit) => format!("{adapter} allows {} MiB", limit / MIB),
        None => format!("{adapter} ran out of memory"),
    };
    format!(
        "The scene is too large for this GPU: {count} Gaussians need a {} MiB buffer and \
         {reason}. Train it again with the draft preset (fewer Gaussians, lower SH degree), \
         or view it on a GPU with more memory.",
        need.div_ceil(MIB)
    )
}

/// Draws scenes with splat-core's forward rasteriser on one device. The Gaussians stay on
/// the GPU: the static set is uploaded once per scene, a dynamic set is copied from its
/// stored twin or uploaded when its timestamp is shown (a version-2 scene's: evaluated on
/// the GPU at the shown time), and frames are drawn into a texture without a trip through
/// the host.
pub struct FrameRenderer {
    renderer: Renderer,
    adapter: AdapterSummary,
    /// The static set followed by the shown dynamic set; `None` until the first
    /// [`Self::show_time`] after [`Self::load_scene`].
    resident: Option<GpuScene>,
    /// Every timestamp's dynamic set when [`Self::load_scene_resident`] kept them; empty
    /// when they are streamed.
    stored: Vec<StoredSet>,
    /// A version-2 scene's spacetime set, uploaded at its first [`Self::show_time`].
    spacetime: Option<GpuSpacetimeSet>,
    playback: Playback,
    /// The loaded scene's rasteriser mode ([`Scene::antialiased`]): every frame is drawn in
    /// it, so that no caller can draw a scene in the other mode than it was trained in.
    antialiased: bool,
    static_len: usize,
    /// The time, in frames, whose dynamic set is resident (a held timestamp's index).
    shown_time: Option<f64>,
    dynamic_len: usize,
    /// The texture [`Self::render`] draws into and reads back.
    own_target: Option<wgpu::Texture>,
    last_render: Duration,
}

impl FrameRenderer {
    /// A renderer on a device of its own (the adapter `PANO4D_ADAPTER` picks).
    pub fn headless() -> Result<Self, String> {
        let ctx = GpuContext::new().map_err(|e| e.to_string())?;
        Self::with_context(ctx)
    }

    /// A renderer on an existing device, e.g. the one egui draws with.
    pub fn on_device(
        device: wgpu::Device,
        queue: wgpu::Queue,
        info: &wgpu::AdapterInfo,
    ) -> Result<Self, String> {
        // Errors outside an error scope (e.g. an allocation that fails) are reported, not
        // turned into a panic inside the window's event loop.
        device.on_uncaptured_error(std::sync::Arc::new(|e: wgpu::Error| {
            eprintln!("pano4d-view: wgpu error: {e}");
        }));
        let adapter = AdapterSummary::from(info);
        Self::with_context(GpuContext {
            device,
            queue,
            adapter,
        })
    }

    fn with_context(ctx: GpuContext) -> Result<Self, String> {
        let adapter = ctx.adapter.clone();
        let renderer =
            Renderer::new(ctx).map_err(|e| format!("cannot build the rasteriser: {e}"))?;
        Ok(Self {
            renderer,
            adapter,
            resident: None,
            stored: Vec::new(),
            spacetime: None,
            playback: Playback::Streamed {
                reason: "no scene loaded".into(),
            },
            antialiased: false,
            static_len: 0,
            shown_time: None,
            dynamic_len: 0,
            own_target: None,
            last_render: Duration::ZERO,
        })
    }

    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    fn device(&self) -> &wgpu::Device {
        &self.renderer.context().device
    }

    /// Forgets the previous scene and takes `scene`'s rasteriser mode; dynamic sets will be
    /// streamed (decoded and uploaded when shown), and the next [`Self::show_time`] uploads
    /// `scene`'s static set (and a version-2 scene's spacetime set, evaluated on the GPU
    /// from then on). For a single view this is all that is needed.
    pub fn load_scene(&mut self, scene: &Scene) {
        self.resident = None;
        self.stored = Vec::new();
        self.spacetime = None;
        self.playback = match scene.time_model() {
            Some(model) => Playback::Evaluated {
                bytes: spacetime_bytes(scene, &model),
            },
            None => Playback::Streamed {
                reason: "loaded for streaming".into(),
            },
        };
        self.antialiased = scene.antialiased;
        self.static_len = scene.static_set.len();
        self.shown_time = None;
        self.dynamic_len = 0;
    }

    /// Loads `scene` for playback: every timestamp's dynamic set is decoded once and kept
    /// on the GPU when [`residency::plan`] says they fit in `budget` bytes (the static set
    /// is uploaded now too), else they are streamed as with [`Self::load_scene`]. Anything
    /// that fails on the way (a damaged set, GPU memory) also leaves them streamed, so
    /// that its error shows at the timestamp it concerns, as when streaming. A version-2
    /// scene has one dynamic set for every time, kept on the GPU whatever the budget
    /// ([`Playback::Evaluated`], as [`Self::load_scene`] leaves it).
    pub fn load_scene_resident(&mut self, scene: &Scene, budget: u64) -> &Playback {
        self.load_scene(scene);
        if scene.time_model().is_some() {
            return &self.playback;
        }
        let planned = scene.dynamic_counts().and_then(|counts| {
            let k = sh_coeffs(scene.sh_degree);
            let max_buffer_size = self.device().limits().max_buffer_size;
            let plan = residency::plan(&counts, k, max_buffer_size, budget);
            if plan.is_resident() {
                self.keep_all(scene, &counts)?;
            }
            Ok(plan)
        });
        self.playback = planned.unwrap_or_else(|reason| {
            self.load_scene(scene);
            Playback::Streamed { reason }
        });
        &self.playback
    }

    /// Uploads the static set and stores every dynamic set (of `counts` Gaussians).
    fn keep_all(&mut self, scene: &Scene, counts: &[usize]) -> Result<(), String> {
        // Room for the static set and the largest dynamic set, exactly: every size is known.
        let largest = counts.iter().copied().max().unwrap_or(0);
        self.resident = Some(self.allocate(self.static_len + largest, scene.sh_degree)?);
        self.write(0, &scene.static_set)?;
        self.stored = (0..counts.len())
            .map(|t| self.store(&scene.dynamic_set(t)?))
            .collect::<Result<_, _>>()?;
        Ok(())
    }

    /// How the loaded scene's dynamic sets reach the GPU.
    pub fn playback(&self) -> &Playback {
        &self.playback
    }

    fn store(&self, set: &GaussianSet) -> Result<StoredSet, String> {
        let ctx = self.renderer.context();
        let out_of_memory = ctx.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let stored = StoredSet::upload(&ctx.device, &ctx.queue, &SceneInput::from(set));
        if pollster::block_on(out_of_memory.pop()).is_some() {
            return Err(format!(
                "{} ran out of memory keeping the dynamic sets; set {} lower to stream them",
                self.adapter.name,
                residency::BUDGET_ENV
            ));
        }
        stored.map_err(|e| e.to_string())
    }

    /// Makes the scene at time `frame` (in frames) the one drawn unless it is the one
    /// shown: a version-2 scene's spacetime set evaluated there on the GPU; any other
    /// scene's timestamp at or before it (each held until the next): a GPU-side copy of its
    /// stored dynamic set, or (streaming) decoding and uploading it.
    pub fn show_time(&mut self, scene: &Scene, frame: f64) -> Result<(), String> {
        if scene.time_model().is_some() {
            return self.show_evaluated(scene, frame);
        }
        let t = frame.max(0.0).floor() as usize;
        if self.shown_time == Some(t as f64) {
            return Ok(());
        }
        let Some(stored) = self.stored.get(t) else {
            return self.show(scene, t, &scene.dynamic_set(t)?);
        };
        let ctx = self.renderer.context();
        let resident = self
            .resident
            .as_mut()
            .expect("allocated when the sets were stored");
        resident
            .copy_from(&ctx.device, &ctx.queue, self.static_len, stored)
            .map_err(|e| e.to_string())?;
        self.dynamic_len = stored.len();
        self.shown_time = Some(t as f64);
        Ok(())
    }

    /// A version-2 scene at `frame`: its spacetime set evaluated on the GPU into the slot
    /// after the static set, both uploaded the first time.
    fn show_evaluated(&mut self, scene: &Scene, frame: f64) -> Result<(), String> {
        if self.shown_time == Some(frame) {
            return Ok(());
        }
        if self.spacetime.is_none() {
            self.keep_spacetime(scene)?;
        }
        let ctx = self.renderer.context();
        let set = self.spacetime.as_ref().expect("kept above");
        let resident = self.resident.as_mut().expect("allocated with the set");
        set.evaluate_into(&ctx.device, &ctx.queue, resident, self.static_len, frame)
            .map_err(|e| e.to_string())?;
        self.dynamic_len = set.len();
        self.shown_time = Some(frame);
        Ok(())
    }

    /// Uploads the static set and `scene`'s spacetime set, with room for its evaluation.
    fn keep_spacetime(&mut self, scene: &Scene) -> Result<(), String> {
        let set = scene.spacetime_set()?;
        self.resident = Some(self.allocate(self.static_len + set.len(), scene.sh_degree)?);
        self.write(0, &scene.static_set)?;
        let ctx = self.renderer.context();
        let out_of_memory = ctx.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let uploaded = GpuSpacetimeSet::upload(&ctx.device, &ctx.queue, &set);
        if pollster::block_on(out_of_memory.pop()).is_some() {
            return Err(format!(
                "{} ran out of memory keeping the spacetime set",
                self.adapter.name
            ));
        }
        let uploaded = uploaded.map_err(|e| match e {
            RasterError::TooLarge {
                gaussians,
                bytes,
                allowed,
            } => too_large_message(gaussians, bytes, Some(allowed), &self.adapter.name),
            e => e.to_string(),
        })?;
        self.spacetime = Some(uploaded);
        Ok(())
    }

    /// Makes timestamp `t`, whose dynamic set is `dynamic` (e.g. decoded ahead by a
    /// [`crate::stream::DynamicStream`]), the one drawn. Uploads the static set first, or
    /// again when a larger dynamic set needs more room.
    pub fn show(&mut self, scene: &Scene, t: usize, dynamic: &GaussianSet) -> Result<(), String> {
        // GpuScene::write checks the set's arrays and its SH degree against the scene.
        let degree = scene.static_set.sh_degree;
        self.shown_time = None;
        let needed = self.static_len + dynamic.len();
        if self.resident.as_ref().is_none_or(|r| r.capacity() < needed) {
            self.resident = None;
            // Headroom, so that dynamic sets of slightly varying size do not re-upload.
            let resident = self
                .allocate(needed + dynamic.len() / 4, degree)
                .or_else(|_| self.allocate(needed, degree))?;
            self.resident = Some(resident);
            self.write(0, &scene.static_set)?;
        }
        self.write(self.static_len, dynamic)?;
        self.dynamic_len = dynamic.len();
        self.shown_time = Some(t as f64);
        Ok(())
    }

    fn allocate(&self, capacity: usize, sh_degree: u32) -> Result<GpuScene, String> {
        let device = self.device();
        let k = sh_coeffs(sh_degree);
        let out_of_memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let created = GpuScene::new(device, capacity, k);
        let failed = pollster::block_on(out_of_memory.pop()).is_some();
        let need = GpuScene::bytes_for(capacity, k);
        let name = &self.adapter.name;
        match created {
            Err(RasterError::TooLarge { allowed, .. }) => {
                Err(too_large_message(capacity, need, Some(allowed), name))
            }
            Err(e) => Err(e.to_string()),
            Ok(_) if failed => Err(too_large_message(capacity, need, None, name)),
            Ok(resident) => Ok(resident),
        }
    }

    fn write(&mut self, first: usize, set: &GaussianSet) -> Result<(), String> {
        let resident = self.resident.as_mut().expect("allocated before writing");
        resident
            .write(
                &self.renderer.context().queue,
                first,
                &SceneInput::from(set),
            )
            .map_err(|e| e.to_string())
    }

    /// The time, in frames, whose Gaussians are drawn.
    pub fn shown_time(&self) -> Option<f64> {
        self.shown_time
    }

    /// (static, dynamic) Gaussians in the frame drawn.
    pub fn counts(&self) -> (usize, usize) {
        (self.static_len, self.dynamic_len)
    }

    /// Time of the last [`Self::draw`], until the GPU finished the frame.
    pub fn last_render_time(&self) -> Duration {
        self.last_render
    }

    /// A texture [`Self::draw`] can draw into and egui can show.
    pub fn create_target(&self, width: u32, height: u32) -> wgpu::Texture {
        target_texture(self.device(), width, height)
    }

    /// Draws the shown timestamp from `camera` with `options`, in the loaded scene's
    /// rasteriser mode, into `target` (a texture from [`Self::create_target`] of the
    /// camera's size).
    pub fn draw(
        &mut self,
        camera: &Camera,
        options: &FrameOptions,
        target: &wgpu::Texture,
    ) -> Result<(), String> {
        let Some(resident) = &self.resident else {
            return Err("no timestamp is shown yet".into());
        };
        let settings = RenderSettings {
            background: options.background,
            antialiased: self.antialiased,
            splat_scale: options.splat_scale.max(1e-3),
        };
        let start = Instant::now();
        let device = self.renderer.context().device.clone();
        // The intersection buffers grow with the view: an allocation that fails shows here.
        let out_of_memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let drawn = self.renderer.draw(resident, camera, &settings, target);
        if pollster::block_on(out_of_memory.pop()).is_some() {
            let k = resident.sh_coeffs();
            let need = GpuScene::bytes_for(resident.len(), k);
            return Err(too_large_message(
                resident.len(),
                need,
                None,
                &self.adapter.name,
            ));
        }
        drawn.map_err(|e| e.to_string())?;
        // Wait for the GPU so that the frame time measures the frame, not its submission.
        self.wait()?;
        self.last_render = start.elapsed();
        Ok(())
    }

    /// Waits until the GPU has done all the work queued so far, buffer writes included.
    pub fn wait(&self) -> Result<(), String> {
        // Writes wait in the queue for the next submission: submit them.
        self.renderer.context().queue.submit([]);
        self.device()
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| e.to_string())
    }

    /// Draws the shown timestamp into a texture of the renderer's own and reads it back.
    pub fn render(&mut self, camera: &Camera, options: &FrameOptions) -> Result<RgbaImage, String> {
        let size = [camera.width, camera.height];
        let target = match &self.own_target {
            Some(t) if [t.width(), t.height()] == size => t.clone(),
            _ => self.create_target(camera.width, camera.height),
        };
        self.own_target = Some(target.clone());
        self.draw(camera, options, &target)?;
        self.read_back(&target)
    }

    /// The pixels of a texture from [`Self::create_target`] (e.g. for a screenshot).
    pub fn read_back(&mut self, target: &wgpu::Texture) -> Result<RgbaImage, String> {
        let bytes = self
            .renderer
            .read_rgba8(target)
            .map_err(|e| e.to_string())?;
        RgbaImage::from_raw(target.width(), target.height(), bytes)
            .ok_or_else(|| "the read-back has the wrong size".into())
    }
}

/// Bytes a version-2 scene's spacetime set takes on the GPU.
fn spacetime_bytes(scene: &Scene, model: &TimeModel) -> u64 {
    let n = scene
        .dynamic_counts()
        .ok()
        .and_then(|counts| counts.first().copied())
        .unwrap_or(0);
    GpuSpacetimeSet::bytes_for(n, sh_coeffs(scene.sh_degree), model)
}

/// Writes `image` as a PNG at `path` atomically (a temporary file beside it, then rename).
pub fn save_png(image: &RgbaImage, path: &Path) -> Result<(), String> {
    let file_name = path
        .file_name()
        .ok_or_else(|| format!("{} is not a file path", path.display()))?;
    let tmp = path.with_file_name(format!(
        ".{}.{}.tmp",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let written = image
        .save_with_format(&tmp, image::ImageFormat::Png)
        .map_err(|e| format!("cannot write {}: {e}", path.display()))
        .and_then(|()| {
            std::fs::rename(&tmp, path).map_err(|e| format!("cannot write {}: {e}", path.display()))
        });
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{SceneExtent, ViewCamera};
    use crate::residency::Playback;
    use crate::synthetic;
    use splat_core::gaussians::SH_C0;
    use splat_core::ply4d;
    use splat_core::raster::binding_limit;

    fn open(tag: &str, static_count: usize, dynamic_count: usize, times: usize) -> Scene {
        let generated = synthetic::scene(static_count, dynamic_count, times, 1, 5);
        open_generated(tag, &generated)
    }

    fn open_generated(tag: &str, generated: &ply4d::Scene4d) -> Scene {
        let dir = std::env::temp_dir().join(format!("pano4d-render-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("scene.ply4d");
        ply4d::write(&path, generated).unwrap();
        let scene = Scene::open(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        scene
    }

    /// Five timestamps whose dynamic sets shrink from 400 to 40 Gaussians.
    fn open_varied(tag: &str) -> Scene {
        let mut generated = synthetic::scene(3_000, 400, 5, 1, 5);
        for (t, set) in generated.dynamic.iter_mut().enumerate() {
            let n = 400 - 90 * t;
            set.means.truncate(n);
            set.log_scales.truncate(n);
            set.quats.truncate(n);
            set.opacity_logits.truncate(n);
            set.sh.truncate(n * 3 * sh_coeffs(set.sh_degree));
        }
        open_generated(tag, &generated)
    }

    fn all_dynamic_bytes(scene: &Scene) -> u64 {
        let k = sh_coeffs(scene.sh_degree);
        let counts = scene.dynamic_counts().unwrap();
        counts.iter().map(|&n| GpuScene::bytes_for(n, k)).sum()
    }

    #[test]
    fn resident_sets_draw_what_streamed_sets_draw_at_every_timestamp() {
        let scene = open_varied("resident-all");
        let all = all_dynamic_bytes(&scene);
        let mut resident = FrameRenderer::headless().unwrap();
        let playback = resident.load_scene_resident(&scene, all);
        assert_eq!(*playback, Playback::Resident { bytes: all });
        let mut streamed = FrameRenderer::headless().unwrap();
        streamed.load_scene(&scene);
        // Forward, backward and jumps: a smaller set after a larger one and the reverse.
        for t in [0, 1, 2, 3, 4, 2, 0, 4, 1] {
            let got = frame(&mut resident, &scene, t, 1.0);
            let want = frame(&mut streamed, &scene, t, 1.0);
            assert_eq!(resident.counts(), streamed.counts(), "timestamp {t}");
            assert_eq!(resident.counts().1, 400 - 90 * t);
            assert!(got.pixels().any(|p| p.0[..3] != [0, 0, 0]), "nothing drawn");
            assert!(got == want, "timestamp {t}");
        }
    }

    #[test]
    fn scenes_over_the_budget_are_streamed_and_draw_the_same() {
        let scene = open_varied("over-budget");
        let all = all_dynamic_bytes(&scene);
        let mut renderer = FrameRenderer::headless().unwrap();
        let playback = renderer.load_scene_resident(&scene, all - 1).clone();
        assert!(!playback.is_resident(), "{playback:?}");
        assert!(playback.describe().contains("budget"), "{playback:?}");
        for t in [3, 0, 4] {
            assert!(frame(&mut renderer, &scene, t, 1.0) == fresh_frame(&scene, t));
        }
        // Loading again with room keeps them, on the same renderer.
        assert!(renderer.load_scene_resident(&scene, all).is_resident());
        assert!(frame(&mut renderer, &scene, 4, 1.0) == fresh_frame(&scene, 4));
    }

    fn frame(renderer: &mut FrameRenderer, scene: &Scene, t: usize, scale: f32) -> RgbaImage {
        frame_at(renderer, scene, t as f64, scale)
    }

    /// The scene at time `frame` (in frames), as [`frame`] draws it.
    fn frame_at(renderer: &mut FrameRenderer, scene: &Scene, frame: f64, scale: f32) -> RgbaImage {
        renderer.show_time(scene, frame).unwrap();
        let camera = ViewCamera::panorama_viewpoint(&scene.extent).to_camera(96, 64);
        let options = FrameOptions {
            splat_scale: scale,
            ..Default::default()
        };
        renderer.render(&camera, &options).unwrap()
    }

    fn fresh_frame(scene: &Scene, t: usize) -> RgbaImage {
        let mut renderer = FrameRenderer::headless().unwrap();
        renderer.load_scene(scene);
        frame(&mut renderer, scene, t, 1.0)
    }

    /// Channel values by which two frames differ at most.
    fn worst_channel(a: &RgbaImage, b: &RgbaImage) -> u8 {
        assert_eq!(a.dimensions(), b.dimensions());
        a.as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0)
    }

    /// The 4-frame version-2 scene `synthetic::spacetime_scene` makes, opened; and the same
    /// scene as a version-1 file whose timestamps are its spacetime set evaluated on the CPU
    /// at `times`.
    fn open_spacetime(tag: &str, times: &[f64]) -> (Scene, Scene) {
        let generated = synthetic::spacetime_scene(3_000, 400, 4, 1, 5);
        let dir = std::env::temp_dir().join(format!("pano4d-render-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("scene.ply4d");
        ply4d::write_spacetime(&path, &generated).unwrap();
        let spacetime = Scene::open(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let mut meta = generated.meta.clone();
        meta.timestamps = times.iter().map(|t| t / synthetic::FPS).collect();
        let evaluated = open_generated(
            &format!("{tag}-evaluated"),
            &ply4d::Scene4d {
                static_set: generated.static_set.clone(),
                dynamic: times.iter().map(|&t| generated.dynamic.at(t)).collect(),
                meta,
            },
        );
        (spacetime, evaluated)
    }

    #[test]
    fn a_version_2_scene_draws_as_the_version_1_scene_of_its_evaluated_sets() {
        let (spacetime, evaluated) = open_spacetime("v2", &[0.0, 1.0, 2.0, 3.0]);
        let mut renderer = FrameRenderer::headless().unwrap();
        renderer.load_scene(&spacetime);
        assert_eq!(
            *renderer.playback(),
            Playback::Evaluated {
                bytes: GpuSpacetimeSet::bytes_for(400, 4, &spacetime.time_model().unwrap())
            }
        );
        for t in [0, 1, 2, 3, 0] {
            let got = frame(&mut renderer, &spacetime, t, 1.0);
            assert_eq!(renderer.counts(), (3_000, 400));
            assert!(got.pixels().any(|p| p.0[..3] != [0, 0, 0]), "nothing drawn");
            // Evaluated on the GPU, summed in another order than on the CPU: float32
            // rounding apart, which may tip a channel by a level.
            let worst = worst_channel(&got, &fresh_frame(&evaluated, t));
            assert!(worst <= 1, "timestamp {t}: off by {worst} levels");
        }
        assert!(
            worst_channel(&fresh_frame(&evaluated, 0), &fresh_frame(&evaluated, 2)) > 100,
            "the ball bobs"
        );
    }

    #[test]
    fn a_version_2_scene_is_drawn_at_any_time_and_loops() {
        // Times between frames, where the held frame would show another set.
        let times = [0.5, 1.25, 2.7];
        let (spacetime, evaluated) = open_spacetime("v2-any-time", &times);
        let mut renderer = FrameRenderer::headless().unwrap();
        // Loaded for playback too: no budget applies, nothing is streamed.
        let playback = renderer.load_scene_resident(&spacetime, 0).clone();
        assert!(
            matches!(playback, Playback::Evaluated { .. }),
            "{playback:?}"
        );
        assert!(!playback.streams());
        for (i, &time) in times.iter().enumerate() {
            let want = fresh_frame(&evaluated, i);
            for shown in [time, time + 4.0, time - 8.0] {
                let got = frame_at(&mut renderer, &spacetime, shown, 1.0);
                assert_eq!(renderer.shown_time(), Some(shown));
                let worst = worst_channel(&got, &want);
                assert!(worst <= 1, "t = {shown}: off by {worst} levels");
            }
            let held = frame(&mut renderer, &spacetime, time.floor() as usize, 1.0);
            assert!(
                worst_channel(&held, &want) > 10,
                "t = {time} draws what its whole frame draws"
            );
        }
    }

    #[test]
    fn resident_frames_match_a_fresh_upload_of_the_same_timestamp() {
        let scene = open("resident", 3_000, 400, 3);
        let mut playing = FrameRenderer::headless().unwrap();
        playing.load_scene(&scene);
        // Play 0 → 1 → 2 → 1 on one renderer: each frame equals that of a renderer that
        // only ever saw its timestamp.
        for t in [0, 1, 2, 1] {
            let got = frame(&mut playing, &scene, t, 1.0);
            let dynamic = scene.dynamic_set(t).unwrap().len();
            assert_eq!(playing.counts(), (3_000, dynamic));
            assert!(got == fresh_frame(&scene, t), "timestamp {t}");
        }
        let lit = |image: &RgbaImage| image.pixels().filter(|p| p.0[..3] != [0, 0, 0]).count();
        let small = frame(&mut playing, &scene, 1, 0.25);
        let normal = frame(&mut playing, &scene, 1, 1.0);
        assert!(
            lit(&small) < lit(&normal),
            "a smaller splat scale covers fewer pixels"
        );
    }

    #[test]
    fn a_scene_is_drawn_in_the_mode_its_file_records() {
        // One white Gaussian straight ahead, 0.3 px wide (σ) in `frame`'s view: sub-pixel,
        // where the modes differ most. Classic dilates it by 0.3 px² at full opacity; the
        // antialiased mode by 0.1 px², its opacity scaled by sqrt(det Σ / det(Σ + 0.1 I)) =
        // 0.09 / 0.19. The view's axis meets a pixel corner (an even size), so the brightest
        // pixels' centres lie (½, ½) px off the mean: each mode's falloff there,
        // exp(−¼ / (σ² + filter)), enters the peaks' ratio too.
        const DISTANCE: f64 = 3.0;
        const SIGMA_PX: f64 = 0.3;
        let extent = SceneExtent {
            median_distance: DISTANCE,
        };
        let fx = ViewCamera::panorama_viewpoint(&extent).to_camera(96, 64).fx;
        let mut generated = synthetic::scene(1, 0, 1, 0, 5);
        let set = &mut generated.static_set;
        set.means[0] = [DISTANCE as f32, 0.0, 0.0];
        set.log_scales[0] = [(SIGMA_PX * DISTANCE / fx).ln() as f32; 3];
        set.sh = vec![0.5 / SH_C0; 3];
        let mut peak = |antialiased: bool| {
            generated.meta.antialiased = antialiased;
            let scene = open_generated("mode", &generated);
            let image = fresh_frame(&scene, 0);
            image.pixels().map(|p| p.0[0]).max().unwrap() as f64
        };
        let classic = peak(false);
        let antialiased = peak(true);
        assert!(classic > 100.0, "the classic splat is bright: {classic}");
        let ratio = antialiased / classic;
        let variance = SIGMA_PX.powi(2);
        let falloff = |filter: f64| (-0.25 / (variance + filter)).exp();
        let expected = variance / (variance + 0.1) * falloff(0.1) / falloff(0.3);
        assert!(
            (ratio - expected).abs() < 0.05,
            "antialiased / classic peak {antialiased} / {classic} = {ratio}, not {expected}"
        );
    }

    #[test]
    fn a_larger_dynamic_set_makes_room_and_keeps_the_static_set() {
        let small = open("grow-small", 2_000, 50, 2);
        let big = open("grow-big", 2_000, 900, 2);
        assert_eq!(small.static_set.means, big.static_set.means);
        let mut renderer = FrameRenderer::headless().unwrap();
        renderer.load_scene(&small);
        let before = frame(&mut renderer, &small, 0, 1.0);
        // The same static set, then a dynamic set the resident buffer has no room for.
        let grown = frame(&mut renderer, &big, 1, 1.0);
        assert_eq!(
            renderer.counts(),
            (2_000, big.dynamic_set(1).unwrap().len())
        );
        assert!(grown == fresh_frame(&big, 1));
        assert!(before != grown);
        // A dynamic set of another SH degree than the scene's is refused.
        let other_degree = synthetic::scene(1, 5, 1, 2, 3).dynamic.remove(0);
        let refused = renderer.show(&big, 0, &other_degree).unwrap_err();
        assert!(refused.contains("SH coefficients"), "{refused}");
    }

    #[test]
    fn a_scene_over_the_device_limit_gets_the_draft_advice() {
        let renderer = FrameRenderer::headless().unwrap();
        let allowed = binding_limit(renderer.device());
        let over = (allowed / GpuScene::bytes_for(1, 16)) as usize + 1;
        if over >= (u32::MAX / 64) as usize {
            return; // an adapter whose limit is beyond what one scene may hold anyway
        }
        let message = renderer.allocate(over, 3).err().expect("too large");
        assert!(
            message.contains("too large") && message.contains("draft preset"),
            "{message}"
        );
    }

    #[test]
    fn buffer_size_and_message() {
        assert_eq!(GpuScene::bytes_for(1_000_000, 16), 4 * 1_000_000 * 59);
        let msg = too_large_message(10, 300 << 20, Some(128 << 20), "lavapipe");
        assert!(msg.contains("300 MiB") && msg.contains("128 MiB") && msg.contains("draft preset"));
        assert!(too_large_message(10, 1, None, "gpu").contains("ran out of memory"));
    }
}
