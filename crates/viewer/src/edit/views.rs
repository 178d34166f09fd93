//! The editor's two views of the panorama and how screen points map to panorama pixels:
//! the equirect image with zoom and pan (u continuous: panning goes round the seam), and
//! the perspective view from the panorama's viewpoint ([`ViewCamera`]'s look-around).
//! Both are drawn on the CPU by sampling the panorama per screen pixel ([`compose`]),
//! tinted where regions are, so a region is drawn right wherever it lies on the sphere.

use eframe::egui::{self, Color32, ColorImage, Pos2, Rect};
use glam::{DVec2, DVec3};
use image::RgbImage;
use splat_core::camera::{dir_to_equirect, equirect_to_dir, Camera};

use crate::camera::{SceneExtent, ViewCamera};

/// The panorama as a chain of halvings, so that a zoomed-out view samples a level whose
/// pixel is about a screen pixel instead of aliasing.
pub struct Pyramid {
    pub levels: Vec<RgbImage>,
}

impl Pyramid {
    pub fn new(image: RgbImage) -> Self {
        let mut levels = vec![image];
        while let Some(last) = levels
            .last()
            .filter(|l| l.width() >= 256 && l.height() >= 2)
        {
            let (w, h) = (last.width() / 2, last.height() / 2);
            let half = RgbImage::from_fn(w, h, |x, y| {
                let mut sum = [0u32; 3];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let p = last.get_pixel(2 * x + dx, 2 * y + dy).0;
                    sum.iter_mut().zip(p).for_each(|(s, c)| *s += c as u32);
                }
                image::Rgb(sum.map(|s| ((s + 2) / 4) as u8))
            });
            levels.push(half);
        }
        Self { levels }
    }

    pub fn width(&self) -> u32 {
        self.levels[0].width()
    }

    /// The level whose pixel covers about `footprint` of the finest level's pixels.
    fn level(&self, footprint: f64) -> &RgbImage {
        &self.levels[(footprint.max(1.0).log2().floor() as usize).min(self.levels.len() - 1)]
    }
}

/// The colour of `image` at fraction (fu, fv) ∈ [0, 1)², nearest pixel.
fn sample(image: &RgbImage, fu: f64, fv: f64) -> [u8; 3] {
    let x = ((fu * image.width() as f64) as u32).min(image.width() - 1);
    let y = ((fv * image.height() as f64) as u32).min(image.height() - 1);
    image.get_pixel(x, y).0
}

/// Which view the editor shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewKind {
    Panorama,
    Perspective,
}

/// The equirect image: `centre` (panorama pixels, u continuous) at the middle of the view,
/// `scale` screen points per panorama pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PanoramaView {
    pub centre: DVec2,
    pub scale: f64,
}

impl PanoramaView {
    /// The whole panorama, centred, as large as `rect` allows.
    pub fn fit(rect: Rect, width: u32, height: u32) -> Self {
        let scale = (rect.width() as f64 / width as f64).min(rect.height() as f64 / height as f64);
        Self {
            centre: DVec2::new(width as f64 / 2.0, height as f64 / 2.0),
            scale,
        }
    }

    pub fn to_pixel(&self, rect: Rect, p: Pos2) -> DVec2 {
        let c = rect.center();
        self.centre + DVec2::new((p.x - c.x) as f64, (p.y - c.y) as f64) / self.scale
    }

    pub fn to_screen(&self, rect: Rect, uv: DVec2) -> Pos2 {
        let d = (uv - self.centre) * self.scale;
        rect.center() + egui::vec2(d.x as f32, d.y as f32)
    }

    /// Moves the image by a drag of `delta` points.
    pub fn pan(&mut self, delta: egui::Vec2) {
        self.centre -= DVec2::new(delta.x as f64, delta.y as f64) / self.scale;
    }

    /// Zooms by `factor` keeping the pixel under `at` in place; never smaller than
    /// `min_scale` (the whole height in view) nor beyond 16 points a pixel.
    pub fn zoom_at(&mut self, rect: Rect, at: Pos2, factor: f64, min_scale: f64) {
        let fixed = self.to_pixel(rect, at);
        self.scale = (self.scale * factor).clamp(min_scale, 16.0);
        self.centre += fixed - self.to_pixel(rect, at);
    }
}

/// The perspective view: a look-around camera at the panorama's viewpoint. A panorama is
/// a sphere at infinity, so only the direction and the field of view matter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PerspectiveView {
    pub camera: ViewCamera,
}

impl Default for PerspectiveView {
    fn default() -> Self {
        Self {
            camera: ViewCamera::panorama_viewpoint(&SceneExtent {
                median_distance: 1.0,
            }),
        }
    }
}

impl PerspectiveView {
    /// The pinhole camera for `rect`, in points relative to its top-left corner.
    pub fn pinhole(&self, rect: Rect) -> Camera {
        let (w, h) = (
            rect.width().round().max(1.0),
            rect.height().round().max(1.0),
        );
        self.camera.to_camera(w as u32, h as u32)
    }

    pub fn to_dir(&self, rect: Rect, p: Pos2) -> DVec3 {
        ray(&self.pinhole(rect), rect, p)
    }

    /// The screen point of direction `d`, None behind the camera.
    pub fn to_screen(&self, rect: Rect, d: DVec3) -> Option<Pos2> {
        let (uv, z) = self.pinhole(rect).project(d);
        (z > 1e-6).then(|| rect.min + egui::vec2(uv.x as f32, uv.y as f32))
    }
}

/// The direction seen at screen point `p` by `camera` (made for `rect`).
fn ray(camera: &Camera, rect: Rect, p: Pos2) -> DVec3 {
    let uv = DVec2::new((p.x - rect.min.x) as f64, (p.y - rect.min.y) as f64);
    camera.unproject_ray(uv, 1.0)
}

/// A view of the panorama in a screen rectangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum View {
    Panorama(PanoramaView),
    Perspective(PerspectiveView),
}

impl View {
    /// The panorama pixel under `p` (u continuous in the equirect view, in [0, W) in the
    /// perspective view), None off the image.
    pub fn to_pixel(&self, rect: Rect, p: Pos2, width: u32, height: u32) -> Option<DVec2> {
        self.mapper(rect, width, height)(p)
    }

    /// [`Self::to_pixel`] for many points: the camera is built once.
    fn mapper(&self, rect: Rect, width: u32, height: u32) -> impl Fn(Pos2) -> Option<DVec2> {
        enum Mapping {
            Flat(PanoramaView),
            Pinhole(Camera),
        }
        let mapping = match self {
            Self::Panorama(view) => Mapping::Flat(*view),
            Self::Perspective(view) => Mapping::Pinhole(view.pinhole(rect)),
        };
        move |p| match &mapping {
            Mapping::Flat(view) => {
                let uv = view.to_pixel(rect, p);
                (0.0..height as f64).contains(&uv.y).then_some(uv)
            }
            Mapping::Pinhole(camera) => Some(dir_to_equirect(ray(camera, rect, p), width, height)),
        }
    }

    /// A path given in panorama pixels (u continuous) as screen polylines: in the equirect
    /// view once for every copy of it round the seam that shows, in the perspective view
    /// cut where it passes behind the camera.
    pub fn polylines(&self, rect: Rect, path: &[DVec2], width: u32, height: u32) -> Vec<Vec<Pos2>> {
        match self {
            Self::Panorama(view) => {
                let w = width as f64;
                let left = view.to_pixel(rect, rect.left_top()).x;
                let right = view.to_pixel(rect, rect.right_top()).x;
                let (lo, hi) = path.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
                    (lo.min(p.x), hi.max(p.x))
                });
                let first = ((left - hi) / w).floor() as i64;
                let last = ((right - lo) / w).ceil() as i64;
                (first..=last)
                    .map(|k| {
                        let shift = DVec2::new(k as f64 * w, 0.0);
                        path.iter()
                            .map(|&p| view.to_screen(rect, p + shift))
                            .collect()
                    })
                    .collect()
            }
            Self::Perspective(view) => {
                let mut lines = vec![Vec::new()];
                for p in path {
                    let d = equirect_to_dir(p.x, p.y, width, height);
                    match view.to_screen(rect, d) {
                        // Far off screen a projected point loses precision: cut there too.
                        Some(s) if rect.expand(4.0 * rect.width()).contains(s) => {
                            lines.last_mut().expect("never empty").push(s)
                        }
                        _ => lines.push(Vec::new()),
                    }
                }
                lines.retain(|l| l.len() > 1);
                lines
            }
        }
    }

    /// How many panorama pixels one screen pixel covers at the view's centre.
    fn footprint(&self, rect: Rect, pixels_per_point: f32, width: u32) -> f64 {
        match self {
            Self::Panorama(view) => 1.0 / (view.scale * pixels_per_point as f64),
            Self::Perspective(view) => {
                let radians =
                    view.camera.fov_deg.to_radians() / (rect.width() * pixels_per_point) as f64;
                radians * width as f64 / std::f64::consts::TAU
            }
        }
    }
}

/// Region tints: the colour of region `i` is `PALETTE[i % len]`.
pub const PALETTE: [Color32; 6] = [
    Color32::from_rgb(255, 80, 80),
    Color32::from_rgb(80, 170, 255),
    Color32::from_rgb(90, 220, 110),
    Color32::from_rgb(255, 190, 40),
    Color32::from_rgb(200, 110, 255),
    Color32::from_rgb(40, 220, 220),
];

pub fn region_colour(index: usize) -> Color32 {
    PALETTE[index % PALETTE.len()]
}

/// Region labels at the editing resolution (see `Document::labels`) and which is selected.
pub struct Tint<'a> {
    pub labels: &'a [u8],
    pub width: u32,
    pub height: u32,
    pub selected: Option<usize>,
}

/// The view as an image of `rect` at `pixels_per_point`: `source` sampled per pixel
/// centre, blended with the colour of the region there (more strongly if selected).
/// Outside the image (above the top, below the bottom) stays dark grey.
pub fn compose(
    view: &View,
    rect: Rect,
    pixels_per_point: f32,
    source: &Pyramid,
    tint: Option<&Tint<'_>>,
    width: u32,
    height: u32,
) -> ColorImage {
    let w_px = (rect.width() * pixels_per_point).round().max(1.0) as usize;
    let h_px = (rect.height() * pixels_per_point).round().max(1.0) as usize;
    let level = source.level(view.footprint(rect, pixels_per_point, source.width()));
    let to_pixel = view.mapper(rect, width, height);
    let shade = |x: usize, y: usize| -> Option<Color32> {
        let p = rect.min
            + egui::vec2(
                (x as f32 + 0.5) / pixels_per_point,
                (y as f32 + 0.5) / pixels_per_point,
            );
        let uv = to_pixel(p)?;
        let (fu, fv) = ((uv.x / width as f64).rem_euclid(1.0), uv.y / height as f64);
        let [r, g, b] = sample(level, fu, fv);
        let mut colour = [r as f32, g as f32, b as f32];
        if let Some(tint) = tint {
            let tx = ((fu * tint.width as f64) as usize).min(tint.width as usize - 1);
            let ty = ((fv * tint.height as f64) as usize).min(tint.height as usize - 1);
            let label = tint.labels[ty * tint.width as usize + tx];
            if label > 0 {
                let index = label as usize - 1;
                let alpha = if tint.selected == Some(index) {
                    0.55
                } else {
                    0.3
                };
                let c = region_colour(index);
                for (v, t) in colour.iter_mut().zip([c.r(), c.g(), c.b()]) {
                    *v += alpha * (t as f32 - *v);
                }
            }
        }
        Some(Color32::from_rgb(
            colour[0] as u8,
            colour[1] as u8,
            colour[2] as u8,
        ))
    };
    let mut pixels = vec![Color32::from_gray(24); w_px * h_px];
    // Bands of rows on every core: a frame is redrawn while the view is dragged.
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let band = h_px.div_ceil(threads).max(1);
    std::thread::scope(|scope| {
        for (k, rows) in pixels.chunks_mut(band * w_px).enumerate() {
            let shade = &shade;
            scope.spawn(move || {
                for (i, row) in rows.chunks_mut(w_px).enumerate() {
                    for (x, out) in row.iter_mut().enumerate() {
                        if let Some(colour) = shade(x, k * band + i) {
                            *out = colour;
                        }
                    }
                }
            });
        }
    });
    ColorImage::new([w_px, h_px], pixels)
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u32 = 512;
    const H: u32 = 256;

    fn rect() -> Rect {
        Rect::from_min_size(Pos2::new(10.0, 20.0), egui::vec2(640.0, 400.0))
    }

    #[test]
    fn equirect_view_maps_both_ways_and_zooms_about_the_cursor() {
        let mut view = PanoramaView::fit(rect(), W, H);
        assert_eq!(view.scale, 1.25);
        let p = Pos2::new(100.0, 300.0);
        let uv = view.to_pixel(rect(), p);
        assert!((view.to_screen(rect(), uv) - p).length() < 1e-4);
        view.zoom_at(rect(), p, 3.0, 0.5);
        assert!((view.to_pixel(rect(), p) - uv).length() < 1e-9);
        view.pan(egui::vec2(-2000.0, 0.0));
        assert!(
            view.to_pixel(rect(), p).x > W as f64,
            "u keeps going past the seam"
        );
    }

    #[test]
    fn perspective_view_round_trips_directions() {
        let mut view = PerspectiveView::default();
        view.camera.look_along(DVec3::new(-1.0, 0.0, 0.2)); // towards the seam
        let p = Pos2::new(200.0, 150.0);
        let d = view.to_dir(rect(), p);
        assert!((view.to_screen(rect(), d).unwrap() - p).length() < 1e-3);
        assert!(view.to_screen(rect(), -d).is_none(), "behind the camera");
        // The centre looks along the camera's forward.
        let centre = View::Perspective(view)
            .to_pixel(rect(), rect().center(), W, H)
            .unwrap();
        let expected = dir_to_equirect(view.camera.forward(), W, H);
        assert!((centre - expected).length() < 1e-6);
    }

    #[test]
    fn a_cap_round_the_pole_is_tinted_as_a_disc_in_both_views() {
        use crate::edit::document::{Document, Mask, Region, Shape};
        use glam::DQuat;
        use std::sync::Arc;

        let radius = 0.15;
        let mut mask = Mask::empty(W, H);
        mask.paint_cap(DVec3::Z, radius, true);
        let doc = Document {
            width: W,
            height: H,
            mask_width: W,
            mask_height: H,
            regions: vec![Region {
                name: None,
                shape: Shape::Mask {
                    mask: Arc::new(mask),
                    file: None,
                },
                motion: None,
            }],
        };
        let labels = doc.labels();
        let tint = Tint {
            labels: &labels,
            width: W,
            height: H,
            selected: None,
        };
        let grey = Pyramid::new(RgbImage::from_pixel(W, H, image::Rgb([128; 3])));
        let tinted = |image: &ColorImage, p: Pos2| {
            let q = p - rect().min;
            image.pixels[q.y as usize * image.size[0] + q.x as usize] != Color32::from_gray(128)
        };
        // Looking up (as far as the camera goes): a disc round the zenith.
        let mut view = PerspectiveView::default();
        view.camera.look_along(DVec3::new(1.0, 0.0, 50.0));
        let image = compose(
            &View::Perspective(view),
            rect(),
            1.0,
            &grey,
            Some(&tint),
            W,
            H,
        );
        for k in 0..16 {
            let azimuth = k as f64 / 16.0 * std::f64::consts::TAU;
            let axis = DVec3::new(azimuth.cos(), azimuth.sin(), 0.0);
            for (scale, inside) in [(0.6, true), (1.4, false)] {
                let d = DQuat::from_axis_angle(axis, scale * radius) * DVec3::Z;
                let p = view.to_screen(rect(), d).unwrap();
                assert_eq!(
                    tinted(&image, p),
                    inside,
                    "azimuth {azimuth:.2}, {scale} × radius"
                );
            }
        }
        // The equirect view: the top rows all the way round.
        let flat = View::Panorama(PanoramaView::fit(rect(), W, H));
        let image = compose(&flat, rect(), 1.0, &grey, Some(&tint), W, H);
        let rows = radius * H as f64 / std::f64::consts::PI;
        for u in (0..W).step_by(7) {
            let top = flat_point(&flat, u as f64 + 0.5, 0.5 * rows);
            let below = flat_point(&flat, u as f64 + 0.5, 1.5 * rows);
            assert!(tinted(&image, top) && !tinted(&image, below), "u = {u}");
        }
    }

    fn flat_point(view: &View, u: f64, v: f64) -> Pos2 {
        let View::Panorama(view) = view else {
            unreachable!()
        };
        view.to_screen(rect(), DVec2::new(u, v))
    }

    #[test]
    fn a_path_across_the_seam_draws_in_every_copy_that_shows() {
        // Zoomed out so that a bit more than one turn shows: the box at the seam appears
        // at both ends of the view.
        let view = View::Panorama(PanoramaView {
            centre: DVec2::new(256.0, 128.0),
            scale: 1.0,
        });
        let path = [DVec2::new(500.0, 100.0), DVec2::new(530.0, 100.0)];
        let lines = view.polylines(rect(), &path, W, H);
        let visible: Vec<_> = lines
            .iter()
            .filter(|l| l.iter().any(|p| rect().contains(*p)))
            .collect();
        assert_eq!(visible.len(), 2, "{lines:?}");
    }
}
