//! The egui application: a view of the scene drawn by [`FrameRenderer`] on egui's own
//! wgpu device, a time bar, and a side panel with counts, timings, camera, camera-path
//! keyframes and render settings. Errors (unreadable files, scenes too large for the GPU)
//! are shown in the window instead of ending the program.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use eframe::egui;
use eframe::egui_wgpu;

use crate::camera::{
    CameraMode, CameraPose, MoveInput, SceneExtent, ViewCamera, MAX_FOV_DEG, MIN_FOV_DEG,
};
use crate::camera_path::{Keyframe, PathDraft};
use crate::render::{save_png, FrameOptions, FrameRenderer};
use crate::residency;
use crate::scene::Scene;
use crate::stream::DynamicStream;
use crate::time::{TimeControl, Timeline};

/// Frame-time smoothing for the fps read-out (weight of the newest frame).
const FPS_SMOOTHING: f64 = 0.1;

/// The texture the scene is drawn into and egui shows.
struct DisplayTexture {
    texture: wgpu::Texture,
    id: egui::TextureId,
}

impl DisplayTexture {
    fn new(
        state: &egui_wgpu::RenderState,
        renderer: &FrameRenderer,
        width: u32,
        height: u32,
    ) -> Self {
        let texture = renderer.create_target(width, height);
        // The rasteriser's colours are display (sRGB-encoded) values, and egui's shader
        // takes texture samples as such (it blends in gamma space): a plain view, no sRGB
        // decode on the way (an Rgba8UnormSrgb view showed every frame too dark).
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            usage: Some(wgpu::TextureUsages::TEXTURE_BINDING),
            ..Default::default()
        });
        let id = state.renderer.write().register_native_texture(
            &state.device,
            &view,
            wgpu::FilterMode::Linear,
        );
        Self { texture, id }
    }

    fn size(&self) -> [u32; 2] {
        [self.texture.width(), self.texture.height()]
    }

    fn free(self, state: &egui_wgpu::RenderState) {
        state.renderer.write().free_texture(&self.id);
    }
}

/// A scene together with its playback state.
struct OpenScene {
    scene: Arc<Scene>,
    /// Decodes the next timestamp while this one is shown; `None` when the dynamic sets are
    /// on the GPU (every timestamp's, or a version-2 scene's one spacetime set).
    stream: Option<DynamicStream>,
    time: TimeControl,
}

/// The viewer window's state.
pub struct ViewerApp {
    opened: Option<OpenScene>,
    renderer: Option<FrameRenderer>,
    /// Shown in place of the scene; the reason nothing (or an old frame) is drawn.
    error: Option<String>,
    camera: ViewCamera,
    extent: SceneExtent,
    options: FrameOptions,
    /// Background colour as shown in the picker (display values).
    background: [u8; 3],
    /// Fraction of the window's pixels rendered (below 1 for slow adapters).
    render_scale: f32,
    display: Option<DisplayTexture>,
    /// Something changed since the last frame was drawn.
    dirty: bool,
    pose_text: String,
    /// The camera path being keyed, in the open scene's coordinates.
    path: PathDraft,
    status: String,
    frame_seconds: f64,
    /// Where the scene was drawn in the last pass, in points.
    view_rect: egui::Rect,
}

impl ViewerApp {
    /// Builds the app on egui's wgpu device and opens `path` if given.
    pub fn new(cc: &eframe::CreationContext<'_>, path: Option<&Path>) -> Self {
        let renderer = match &cc.wgpu_render_state {
            Some(state) => FrameRenderer::on_device(
                state.device.clone(),
                state.queue.clone(),
                &state.adapter.get_info(),
            ),
            None => Err("pano4d-view needs eframe's wgpu renderer, which is not running".into()),
        };
        let extent = SceneExtent {
            median_distance: 1.0,
        };
        let mut app = Self {
            opened: None,
            error: None,
            camera: ViewCamera::panorama_viewpoint(&extent),
            extent,
            options: FrameOptions::default(),
            background: [0; 3],
            render_scale: 1.0,
            display: None,
            dirty: true,
            pose_text: String::new(),
            path: PathDraft::default(),
            status: String::new(),
            frame_seconds: 0.0,
            view_rect: egui::Rect::NOTHING,
            renderer: None,
        };
        match renderer {
            Ok(r) => app.renderer = Some(r),
            Err(e) => app.error = Some(e),
        }
        if let Some(path) = path {
            app.open(path);
        }
        app
    }

    /// Opens a scene, replacing the current one; failures are shown in the window. Its
    /// dynamic sets stay on the GPU when they fit the budget ([`residency`]); a version-2
    /// scene's spacetime set always does.
    pub fn open(&mut self, path: &Path) {
        let opened = Scene::open(path).map_err(|e| format!("Cannot open {}: {e}", path.display()));
        let loaded = opened.and_then(|scene| {
            let streams = match &mut self.renderer {
                Some(renderer) => {
                    let budget = residency::budget_from_env()?;
                    renderer.load_scene_resident(&scene, budget).streams()
                }
                None => true,
            };
            Ok((scene, streams))
        });
        match loaded {
            Ok((scene, streams)) => {
                self.extent = scene.extent;
                self.camera = ViewCamera::panorama_viewpoint(&self.extent);
                // Keyframes are poses in the scene's coordinates: a new scene starts anew.
                self.path = PathDraft::for_scene(path);
                let scene = Arc::new(scene);
                self.opened = Some(OpenScene {
                    time: TimeControl::new(&scene.timestamps, scene.timeline()),
                    stream: streams.then(|| DynamicStream::new(Arc::clone(&scene))),
                    scene,
                });
                if self.renderer.is_some() {
                    self.error = None;
                }
            }
            Err(e) => {
                self.opened = None;
                self.error = Some(e);
            }
        }
        self.dirty = true;
    }

    /// The error shown in the window, if any.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    pub fn camera(&self) -> &ViewCamera {
        &self.camera
    }

    /// The timestamp index at or before the shown time.
    pub fn time_index(&self) -> Option<usize> {
        self.opened.as_ref().map(|o| o.time.index())
    }

    /// The scene's time and how it moves (e.g. its shown time in frames).
    pub fn time(&self) -> Option<&TimeControl> {
        self.opened.as_ref().map(|o| &o.time)
    }

    /// The time, in frames, whose Gaussians the view was last drawn with.
    pub fn drawn_frame(&self) -> Option<f64> {
        self.renderer.as_ref().and_then(|r| r.shown_time())
    }

    /// Where the scene was drawn in the last pass, in points.
    pub fn view_rect(&self) -> egui::Rect {
        self.view_rect
    }

    /// The camera path being keyed.
    pub fn camera_path(&self) -> &PathDraft {
        &self.path
    }

    fn handle_keys(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        let (input, dt, reset, toggle_mode, toggle_play, step, keyframe) = ctx.input(|i| {
            let axis = |plus: egui::Key, minus: egui::Key| {
                i.key_down(plus) as i32 as f64 - i.key_down(minus) as i32 as f64
            };
            let input = MoveInput {
                forward: axis(egui::Key::W, egui::Key::S),
                right: axis(egui::Key::D, egui::Key::A),
                up: axis(egui::Key::E, egui::Key::Q),
                fast: i.modifiers.shift,
            };
            let step =
                i.key_pressed(egui::Key::Period) as i64 - i.key_pressed(egui::Key::Comma) as i64;
            (
                input,
                i.stable_dt as f64,
                i.key_pressed(egui::Key::R),
                i.key_pressed(egui::Key::Tab),
                i.key_pressed(egui::Key::Space),
                step,
                i.key_pressed(egui::Key::K),
            )
        });
        if !input.is_idle() {
            self.camera.step(&input, dt.min(0.1));
            self.dirty = true;
            ctx.request_repaint();
        }
        if reset {
            self.camera = ViewCamera::panorama_viewpoint(&self.extent);
            self.dirty = true;
        }
        if toggle_mode {
            let mode = match self.camera.mode {
                CameraMode::Fly => CameraMode::Orbit,
                CameraMode::Orbit => CameraMode::Fly,
            };
            self.camera.set_mode(mode);
        }
        if let Some(open) = &mut self.opened {
            if toggle_play {
                open.time.toggle_play();
            }
            if step != 0 {
                open.time.step(step);
            }
        }
        if keyframe {
            self.add_keyframe(ctx.pixels_per_point());
        }
    }

    /// Adds the current view to the camera path: its pose, its vertical FOV in the view's
    /// shape and, for a dynamic scene, the shown time over the loop (frame / timestamps).
    fn add_keyframe(&mut self, pixels_per_point: f32) {
        let Some(open) = &self.opened else {
            self.status = "Open a scene to key its camera path".into();
            return;
        };
        // The view in physical pixels, whatever the render resolution: its shape.
        let size = self.view_rect.size() * pixels_per_point;
        let [width, height] = [size.x, size.y].map(|v| v.max(0.0).round() as u32);
        if width == 0 || height == 0 {
            self.status = "No view to take a keyframe of yet".into();
            return;
        }
        let render_time = open
            .scene
            .is_dynamic()
            .then(|| open.time.frame() / open.time.count() as f64);
        let keyframe = Keyframe::of_view(&self.camera, width, height, render_time);
        self.path.add(keyframe, [width, height]);
        self.status = format!("Keyframe {} added", self.path.keyframes.len());
    }

    fn advance_time(&mut self, ctx: &egui::Context) {
        let dt = ctx.input(|i| i.stable_dt as f64);
        if let Some(open) = &mut self.opened {
            if open.time.advance(dt) {
                self.dirty = true;
            }
            if open.time.playing {
                ctx.request_repaint();
            }
        }
    }

    /// Draws a new frame if anything changed; errors replace the view with a message.
    fn render_if_needed(
        &mut self,
        state: Option<&egui_wgpu::RenderState>,
        width: u32,
        height: u32,
    ) {
        let (Some(renderer), Some(open), Some(state)) =
            (&mut self.renderer, &mut self.opened, state)
        else {
            return;
        };
        let size_changed = self
            .display
            .as_ref()
            .is_none_or(|d| d.size() != [width, height]);
        let time_changed = renderer.shown_time() != Some(open.time.frame());
        if !(self.dirty || size_changed || time_changed) {
            return;
        }
        self.dirty = false;
        if size_changed {
            if let Some(old) = self.display.take() {
                old.free(state);
            }
            self.display = Some(DisplayTexture::new(state, renderer, width, height));
        }
        let display = self.display.as_ref().expect("created above");
        let camera = self.camera.to_camera(width, height);
        let shown = match (&mut open.stream, time_changed) {
            (_, false) => Ok(()),
            // Every dynamic set on the GPU: a GPU-side copy; or a version-2 scene's spacetime
            // set evaluated on the GPU at the shown time.
            (None, true) => renderer.show_time(&open.scene, open.time.frame()),
            (Some(stream), true) => {
                let t = open.time.index();
                let shown = stream
                    .take(t)
                    .and_then(|dynamic| renderer.show(&open.scene, t, &dynamic));
                if open.time.playing {
                    stream.prefetch((t + 1) % open.time.count());
                }
                shown
            }
        };
        let drawn = shown.and_then(|()| renderer.draw(&camera, &self.options, &display.texture));
        match drawn {
            Ok(()) => self.error = None,
            Err(e) => {
                self.error = Some(e);
                // Do not retry a failing frame on every repaint; a change retries it.
                if let Some(display) = self.display.take() {
                    display.free(state);
                }
            }
        }
    }

    fn screenshot(&mut self) {
        let (Some(display), Some(open), Some(renderer)) =
            (&self.display, &self.opened, &mut self.renderer)
        else {
            self.status = "Nothing to save yet".into();
            return;
        };
        let frame = match renderer.read_back(&display.texture) {
            Ok(frame) => frame,
            Err(e) => {
                self.status = e;
                return;
            }
        };
        let stem = Path::new(&open.scene.name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        let mut n = 0;
        let path = loop {
            let candidate = PathBuf::from(format!(
                "pano4d-view-{stem}-t{}-{n}.png",
                frame_label(open.time.frame())
            ));
            if !candidate.exists() {
                break candidate;
            }
            n += 1;
        };
        self.status = match save_png(&frame, &path) {
            Ok(()) => format!("Saved {}", path.display()),
            Err(e) => e,
        };
    }

    fn side_panel(&mut self, ui: &mut egui::Ui) {
        ui.heading("pano4d-view");
        if let Some(open) = &self.opened {
            ui.label(open.scene.name.as_str());
        }
        ui.separator();
        egui::Grid::new("stats").num_columns(2).show(ui, |ui| {
            let (statics, dynamics) = self.renderer.as_ref().map_or((0, 0), |r| r.counts());
            ui.label("Static Gaussians");
            ui.label(statics.to_string());
            ui.end_row();
            ui.label("Dynamic Gaussians");
            ui.label(dynamics.to_string());
            ui.end_row();
            if let Some(open) = &self.opened {
                ui.label("Mode").on_hover_text(
                    "The rasteriser mode the scene was trained in, which its .ply4d records \
                     (a plain .ply is classic); it is drawn in that mode",
                );
                ui.label(if open.scene.antialiased {
                    "antialiased (2D filter)"
                } else {
                    "classic"
                });
                ui.end_row();
            }
            ui.label("fps");
            let fps = if self.frame_seconds > 0.0 {
                1.0 / self.frame_seconds
            } else {
                0.0
            };
            ui.label(format!("{fps:.1}"));
            ui.end_row();
            ui.label("Frame time");
            let render = self
                .renderer
                .as_ref()
                .map_or(Duration::ZERO, |r| r.last_render_time());
            ui.label(format!("{:.1} ms", render.as_secs_f64() * 1e3));
            ui.end_row();
            ui.label("Adapter");
            ui.label(
                self.renderer
                    .as_ref()
                    .map_or("none", |r| r.adapter().name.as_str()),
            );
            ui.end_row();
            let dynamic = self.opened.as_ref().is_some_and(|o| o.scene.is_dynamic());
            if let (Some(renderer), true) = (&self.renderer, dynamic) {
                ui.label("Timestamps");
                ui.label(renderer.playback().describe());
                ui.end_row();
            }
        });
        ui.separator();
        ui.label("Camera");
        ui.horizontal(|ui| {
            let mut mode = self.camera.mode;
            ui.radio_value(&mut mode, CameraMode::Fly, "Fly");
            ui.radio_value(&mut mode, CameraMode::Orbit, "Orbit");
            if mode != self.camera.mode {
                self.camera.set_mode(mode);
            }
            if ui.button("Reset (R)").clicked() {
                self.camera = ViewCamera::panorama_viewpoint(&self.extent);
                self.dirty = true;
            }
        });
        let fov = ui.add(
            egui::Slider::new(&mut self.camera.fov_deg, MIN_FOV_DEG..=MAX_FOV_DEG).text("FOV °"),
        );
        let speed = self.extent.walking_speed();
        ui.add(
            egui::Slider::new(&mut self.camera.speed, speed * 0.01..=speed * 100.0)
                .logarithmic(true)
                .text("speed"),
        );
        self.dirty |= fov.changed();
        let pose_label = ui.label("Pose (for pano4d render --camera):");
        let pose_line = self.camera.pose().to_line();
        ui.horizontal(|ui| {
            if ui.button("Copy").clicked() {
                ui.ctx().copy_text(pose_line.clone());
                self.status = "Pose copied".into();
            }
            if ui
                .button("Paste pose")
                .on_hover_text("Apply the pose typed below")
                .clicked()
            {
                match CameraPose::parse(&self.pose_text) {
                    Ok(pose) => {
                        self.camera.set_pose(&pose);
                        self.dirty = true;
                        self.status = "Pose applied".into();
                    }
                    Err(e) => self.status = e,
                }
            }
        });
        ui.add(egui::Label::new(egui::RichText::new(&pose_line).monospace().small()).wrap());
        ui.add(egui::TextEdit::singleline(&mut self.pose_text).hint_text("paste a pose line"))
            .labelled_by(pose_label.id);
        ui.separator();
        self.camera_path_panel(ui);
        ui.separator();
        ui.label("Rendering");
        ui.horizontal(|ui| {
            ui.label("Background");
            if egui::color_picker::color_edit_button_srgb(ui, &mut self.background).changed() {
                self.options.background = self.background.map(|c| c as f32 / 255.0);
                self.dirty = true;
            }
        });
        let scale =
            ui.add(egui::Slider::new(&mut self.options.splat_scale, 0.1..=2.0).text("splat scale"));
        let resolution =
            ui.add(egui::Slider::new(&mut self.render_scale, 0.1..=1.0).text("resolution"));
        self.dirty |= scale.changed() || resolution.changed();
        if ui.button("Screenshot (PNG)").clicked() {
            self.screenshot();
        }
        if !self.status.is_empty() {
            ui.label(&self.status);
        }
        ui.separator();
        ui.label(
            "W/A/S/D/Q/E move (shift: faster) · drag: look · scroll: speed (orbit: distance) · \
             ctrl+scroll: FOV · Tab: fly/orbit · R: reset · space: play · , / .: frame step · \
             K: keyframe",
        );
    }

    /// Keyframes, the video they make and where its `camera_path.json` goes.
    fn camera_path_panel(&mut self, ui: &mut egui::Ui) {
        ui.label("Camera path").on_hover_text(
            "Keyframes of a video, saved as nerfstudio's camera_path.json: \
             pano4d render scene.ply4d --path camera_path.json --out v.mp4",
        );
        let keyed = !self.path.keyframes.is_empty();
        ui.horizontal(|ui| {
            if ui
                .button("Add keyframe (K)")
                .on_hover_text("The current view (and the shown time)")
                .clicked()
            {
                self.add_keyframe(ui.ctx().pixels_per_point());
            }
            if ui
                .add_enabled(keyed, egui::Button::new("Remove last"))
                .clicked()
            {
                self.path.keyframes.pop();
            }
            if ui.add_enabled(keyed, egui::Button::new("Clear")).clicked() {
                self.path.keyframes.clear();
            }
        });
        ui.label(format!("{} keyframes", self.path.keyframes.len()));
        let timestamps = self.opened.as_ref().map_or(1, |o| o.time.count());
        for (i, key) in self.path.keyframes.iter().enumerate() {
            let p = key.camera.camera_to_world.w_axis;
            let mut line = format!(
                "{}: ({:.2}, {:.2}, {:.2}) {:.1}°",
                i + 1,
                p.x,
                p.y,
                p.z,
                key.camera.fov_deg
            );
            if let Some(t) = key.camera.render_time {
                line += &format!(" t {:.2}", t * timestamps as f64);
            }
            ui.label(egui::RichText::new(line).monospace().small());
        }
        let video = &mut self.path.video;
        ui.horizontal(|ui| {
            ui.add(
                egui::DragValue::new(&mut video.seconds)
                    .range(0.1..=3600.0)
                    .speed(0.1)
                    .suffix(" s"),
            )
            .on_hover_text("The video's length; every keyframe-to-keyframe transition as long");
            ui.add(
                egui::DragValue::new(&mut video.fps)
                    .range(1.0..=240.0)
                    .suffix(" fps"),
            );
        });
        ui.horizontal(|ui| {
            let size = 1..=16384;
            ui.add(egui::DragValue::new(&mut video.width).range(size.clone()))
                .on_hover_text("Render width: the view's when the first keyframe is added");
            ui.label("×");
            ui.add(egui::DragValue::new(&mut video.height).range(size))
                .on_hover_text("Render height: the view's when the first keyframe is added");
            ui.label(format!("{} frames", video.frame_count()));
        });
        ui.horizontal(|ui| {
            let label = ui.label("File");
            ui.add(egui::TextEdit::singleline(&mut self.path.file).hint_text("camera_path.json"))
                .labelled_by(label.id);
        });
        let save = ui.add_enabled(
            self.path.keyframes.len() >= 2,
            egui::Button::new("Save camera path…"),
        );
        if save.on_disabled_hover_text("Needs two keyframes").clicked() {
            self.status = self.path.save().unwrap_or_else(|e| e);
        }
    }

    fn time_panel(&mut self, ui: &mut egui::Ui) {
        let Some(open) = &mut self.opened else {
            ui.label("No scene");
            return;
        };
        let time = &mut open.time;
        ui.horizontal(|ui| {
            if ui
                .button("< Frame")
                .on_hover_text("Previous frame (,)")
                .clicked()
            {
                time.step(-1);
            }
            let label = if time.playing { "Pause" } else { "Play" };
            if ui.button(label).clicked() {
                time.toggle_play();
            }
            if ui
                .button("Frame >")
                .on_hover_text("Next frame (.)")
                .clicked()
            {
                time.step(1);
            }
            ui.checkbox(&mut time.looping, "Loop");
            ui.add(
                egui::DragValue::new(&mut time.speed)
                    .range(0.05..=8.0)
                    .speed(0.01)
                    .prefix("speed ")
                    .suffix("×"),
            )
            .on_hover_text("Playback speed: scene seconds per second");
            // The slider is in frames (timestamp indices): whole ones where each timestamp
            // is held, any real time in a version-2 scene's loop.
            let mut frame = time.frame();
            let slider = match time.timeline() {
                Timeline::Held => egui::Slider::new(&mut frame, 0.0..=time.end())
                    .integer()
                    .text("time"),
                Timeline::Continuous => egui::Slider::new(&mut frame, 0.0..=time.end())
                    .max_decimals(2)
                    .text("time"),
            };
            ui.add_enabled(time.end() > 0.0, slider);
            if frame != time.frame() {
                time.set_frame(frame);
            }
            ui.label(format!("{:.2} s", time.seconds()));
            if !open.scene.is_dynamic() {
                ui.label("(static scene)");
            }
        });
    }

    fn view(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame) {
        let rect = ui.available_rect_before_wrap();
        self.view_rect = rect;
        let response = ui.interact(
            rect,
            ui.make_persistent_id("view"),
            egui::Sense::click_and_drag(),
        );
        if response.dragged() {
            let delta = response.drag_delta();
            self.camera.drag(delta.x as f64, delta.y as f64);
            self.dirty = true;
        }
        if response.hovered() {
            let (scroll, ctrl) =
                ui.input(|i| (i.smooth_scroll_delta.y as f64, i.modifiers.command));
            if scroll != 0.0 {
                if ctrl {
                    self.camera.zoom(scroll / 50.0);
                } else {
                    self.camera.scroll(scroll / 50.0);
                }
                self.dirty = true;
            }
        }
        let ppp = ui.ctx().pixels_per_point();
        let width = ((rect.width() * ppp * self.render_scale).round() as u32).max(1);
        let height = ((rect.height() * ppp * self.render_scale).round() as u32).max(1);
        self.render_if_needed(frame.wgpu_render_state(), width, height);

        if let Some(error) = &self.error {
            ui.scope_builder(egui::UiBuilder::new().max_rect(rect.shrink(16.0)), |ui| {
                ui.heading("Cannot show the scene");
                ui.colored_label(ui.visuals().error_fg_color, error.as_str());
            });
            return;
        }
        if let Some(display) = &self.display {
            let image = egui::Image::new(egui::load::SizedTexture::new(display.id, rect.size()));
            ui.put(rect, image);
        }
        if let Some(hint) = self.camera.support_hint(&self.extent) {
            let at = rect.left_top() + egui::vec2(8.0, 8.0);
            ui.painter().text(
                at,
                egui::Align2::LEFT_TOP,
                hint,
                egui::FontId::proportional(14.0),
                ui.visuals().warn_fg_color,
            );
        }
    }
}

/// The shown time in a screenshot's name: the timestamp index, with two decimals between
/// timestamps ("0002", "0002.35").
fn frame_label(frame: f64) -> String {
    if frame.fract() == 0.0 {
        format!("{:04}", frame as usize)
    } else {
        format!("{frame:07.2}")
    }
}

impl eframe::App for ViewerApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        let dt = ctx.input(|i| i.stable_dt as f64);
        self.frame_seconds += FPS_SMOOTHING * (dt - self.frame_seconds);
        self.handle_keys(&ctx);
        self.advance_time(&ctx);
        egui::Panel::right("settings")
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.side_panel(ui));
            });
        egui::Panel::bottom("time").show(ui, |ui| self.time_panel(ui));
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| self.view(ui, frame));
    }
}
