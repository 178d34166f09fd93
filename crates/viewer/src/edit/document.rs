//! The regions being edited, as scene.yaml has them, in panorama pixels (u right, v down,
//! origin at the top-left, pixel centres at +0.5): boxes (`u0 > u1` crosses the 0°/360°
//! seam), clicks that grow into a square box, and painted masks. Every direction goes
//! through splat-core's [`equirect_to_dir`] / [`dir_to_equirect`], the project's
//! conventions: a brush dab is a cap on the sphere, as round at a pole as at the horizon,
//! and a motion arrow follows the rotation the animator will apply.

use std::path::Path;
use std::sync::Arc;

use glam::{DQuat, DVec2, DVec3};
use serde::{Deserialize, Serialize};
use splat_core::camera::{dir_to_equirect, equirect_to_dir};

/// scene.yaml's motion hint, and its default when a region has none (`pano4d.config.Motion()`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Motion {
    /// In the image: 0 = towards +u, 90 = towards the zenith.
    pub direction_deg: f64,
    /// Degrees of arc per frame.
    pub speed: f64,
}

pub const DEFAULT_MOTION: Motion = Motion {
    direction_deg: 0.0,
    speed: 0.5,
};

/// The side of a click region's square when scene.yaml gives no `size` (the default of
/// `pano4d.config.Region.pixel_box`).
pub const DEFAULT_CLICK_SIZE: f64 = 256.0;

/// A box [u0, v0, u1, v1] in panorama pixels; `u0 > u1` crosses the seam.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelBox {
    pub u0: f64,
    pub v0: f64,
    pub u1: f64,
    pub v1: f64,
}

impl PixelBox {
    /// The box spanned by two dragged corners, rounded to whole pixels; None if it has no
    /// area. `u` is continuous, not wrapped: a drag from `W − 20` to `W + 20` crosses the
    /// seam and gives `[W − 20, v0, 20, v1]`; a drag over the whole width gives `[0, W]`.
    pub fn from_corners(a: DVec2, b: DVec2, width: u32, height: u32) -> Option<Self> {
        let w = width as f64;
        let (lo, hi) = (a.x.min(b.x).round(), a.x.max(b.x).round());
        let clamp_v = |v: f64| v.clamp(0.0, height as f64).round();
        let (v0, v1) = (clamp_v(a.y.min(b.y)), clamp_v(a.y.max(b.y)));
        if hi - lo < 1.0 || v1 - v0 < 1.0 {
            return None;
        }
        if hi - lo >= w {
            return Some(Self {
                u0: 0.0,
                v0,
                u1: w,
                v1,
            });
        }
        let u0 = lo.rem_euclid(w);
        let u1 = match hi.rem_euclid(w) {
            0.0 => w, // ends on the seam: the box runs to the right edge
            u => u,
        };
        Some(Self { u0, v0, u1, v1 })
    }

    pub fn wraps(&self) -> bool {
        self.u0 > self.u1
    }

    /// Width in u, across the seam for a wrapping box.
    pub fn span(&self, width: u32) -> f64 {
        if self.wraps() {
            self.u1 + width as f64 - self.u0
        } else {
            self.u1 - self.u0
        }
    }

    /// Whether the pixel centre (u, v) lies in the box: `pano4d.regions.region_mask`'s rule.
    pub fn contains(&self, u: f64, v: f64) -> bool {
        let in_u = if self.wraps() {
            u >= self.u0 || u < self.u1
        } else {
            u >= self.u0 && u < self.u1
        };
        in_u && v >= self.v0 && v < self.v1
    }

    /// The centre, wrapped into [0, W).
    pub fn centre(&self, width: u32) -> DVec2 {
        let u = (self.u0 + self.span(width) / 2.0).rem_euclid(width as f64);
        DVec2::new(u, (self.v0 + self.v1) / 2.0)
    }

    /// The outline as a closed path with `per_side` points a side, u continuous from u0.
    pub fn outline(&self, width: u32, per_side: usize) -> Vec<DVec2> {
        let (u0, u1) = (self.u0, self.u0 + self.span(width));
        let corners = [
            DVec2::new(u0, self.v0),
            DVec2::new(u1, self.v0),
            DVec2::new(u1, self.v1),
            DVec2::new(u0, self.v1),
        ];
        let mut path = Vec::with_capacity(4 * per_side + 1);
        for side in 0..4 {
            let (a, b) = (corners[side], corners[(side + 1) % 4]);
            path.extend((0..per_side).map(|k| a.lerp(b, k as f64 / per_side as f64)));
        }
        path.push(corners[0]);
        path
    }
}

/// A painted mask at the editing resolution: one byte per pixel, 1 = moves.
#[derive(Clone, PartialEq, Eq)]
pub struct Mask {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

impl std::fmt::Debug for Mask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Mask({}×{}, {} set)",
            self.width,
            self.height,
            self.count()
        )
    }
}

impl Mask {
    pub fn empty(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            pixels: vec![0; width as usize * height as usize],
        }
    }

    /// Reads a mask PNG (white = moves), as `pano4d regions show` writes them.
    pub fn from_png(path: &Path) -> Result<Self, String> {
        let image = image::open(path)
            .map_err(|e| format!("cannot read the mask {}: {e}", path.display()))?
            .into_luma8();
        Ok(Self {
            width: image.width(),
            height: image.height(),
            pixels: image.pixels().map(|p| (p.0[0] > 127) as u8).collect(),
        })
    }

    /// Writes the mask as an 8-bit grey PNG (0 or 255).
    pub fn save_png(&self, path: &Path) -> Result<(), String> {
        let pixels = self.pixels.iter().map(|&p| p * 255).collect();
        let image = image::GrayImage::from_raw(self.width, self.height, pixels)
            .expect("one byte per pixel");
        image
            .save_with_format(path, image::ImageFormat::Png)
            .map_err(|e| format!("cannot write the mask {}: {e}", path.display()))
    }

    pub fn get(&self, x: u32, y: u32) -> bool {
        self.pixels[y as usize * self.width as usize + x as usize] != 0
    }

    /// The mask at panorama pixel coordinates (u, v) of a `width`×`height` panorama
    /// (nearest pixel, as `pano4d.images.read_mask` resizes).
    pub fn at(&self, u: f64, v: f64, width: u32, height: u32) -> bool {
        let x = (u.rem_euclid(width as f64) * self.width as f64 / width as f64) as u32;
        let y = (v * self.height as f64 / height as f64) as i64;
        (0..self.height as i64).contains(&y) && self.get(x.min(self.width - 1), y as u32)
    }

    pub fn count(&self) -> usize {
        self.pixels.iter().filter(|&&p| p != 0).count()
    }

    /// Sets (`value` true) or clears every pixel whose centre lies within `radius` radians
    /// of the direction `centre`: a cap on the sphere, found row by row (on each row the
    /// cap is one run of columns, wrapping across the seam; a row near a pole the cap
    /// covers is covered whole).
    pub fn paint_cap(&mut self, centre: DVec3, radius: f64, value: bool) {
        let c = centre.normalize();
        let (w, h) = (self.width, self.height);
        let uc = dir_to_equirect(c, w, h).x;
        let (sin_c, cos_c) = (c.z, c.x.hypot(c.y));
        let cos_r = radius.cos();
        for y in 0..h {
            let row = equirect_to_dir(0.5, y as f64 + 0.5, w, h);
            let (sin_y, cos_y) = (row.z, row.x.hypot(row.y));
            // cos(distance) = sin_c sin_y + cos_c cos_y cos(Δφ) ≥ cos r  ⇔  cos(Δφ) ≥ k
            let denominator = cos_c * cos_y;
            let k = if denominator < 1e-12 {
                if sin_c * sin_y >= cos_r {
                    -1.0
                } else {
                    2.0
                }
            } else {
                (cos_r - sin_c * sin_y) / denominator
            };
            if k > 1.0 {
                continue;
            }
            let half = k.max(-1.0).acos() * w as f64 / std::f64::consts::TAU;
            let start = y as usize * w as usize;
            let row_pixels = &mut self.pixels[start..start + w as usize];
            if half >= w as f64 / 2.0 {
                row_pixels.fill(value as u8);
                continue;
            }
            let first = (uc - half - 0.5).ceil() as i64;
            let last = (uc + half - 0.5).floor() as i64;
            for x in first..=last {
                row_pixels[x.rem_euclid(w as i64) as usize] = value as u8;
            }
        }
    }
}

/// What a region selects.
#[derive(Clone, Debug)]
pub enum Shape {
    Box(PixelBox),
    /// A click grows into a `size`-pixel square centred on it (wrapped in u, clipped in v).
    Click {
        at: DVec2,
        size: f64,
    },
    /// `file` is the path as scene.yaml writes it while the mask is unpainted; painting
    /// clears it, and saving writes the mask beside scene.yaml.
    Mask {
        mask: Arc<Mask>,
        file: Option<String>,
    },
}

impl PartialEq for Shape {
    /// Masks compare by identity: an edit replaces the shared mask (copy on write), so a
    /// snapshot equals the current state exactly when nothing was painted since.
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Self::Box(a), Self::Box(b)) => a == b,
            (Self::Click { at: a, size: s }, Self::Click { at: b, size: t }) => a == b && s == t,
            (Self::Mask { mask: a, file: f }, Self::Mask { mask: b, file: g }) => {
                Arc::ptr_eq(a, b) && f == g
            }
            _ => false,
        }
    }
}

/// One region: a shape, an optional name and an optional motion hint.
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    pub name: Option<String>,
    pub shape: Shape,
    pub motion: Option<Motion>,
}

impl Region {
    pub fn kind(&self) -> &'static str {
        match self.shape {
            Shape::Box(_) => "box",
            Shape::Click { .. } => "click",
            Shape::Mask { .. } => "mask",
        }
    }

    /// The name, or "region N" for the `index`-th region without one.
    pub fn label(&self, index: usize) -> String {
        self.name
            .clone()
            .unwrap_or_else(|| format!("region {}", index + 1))
    }

    /// The motion the animator uses: the hint, or the default one.
    pub fn motion_or_default(&self) -> Motion {
        self.motion.unwrap_or(DEFAULT_MOTION)
    }
}

/// The square box a click grows into: `pano4d.config.Region.pixel_box` for a click.
pub fn click_box(at: DVec2, size: f64, width: u32, height: u32) -> PixelBox {
    let (w, h) = (width as f64, height as f64);
    let half = size / 2.0;
    let (v0, v1) = ((at.y - half).max(0.0), (at.y + half).min(h));
    if 2.0 * half >= w {
        return PixelBox {
            u0: 0.0,
            v0,
            u1: w,
            v1,
        };
    }
    PixelBox {
        u0: (at.x - half).rem_euclid(w),
        v0,
        u1: (at.x + half).rem_euclid(w),
        v1,
    }
}

/// `u + k·W` nearest to `reference`: continues a path across the seam.
pub fn unwrap_near(u: f64, reference: f64, width: u32) -> f64 {
    let w = width as f64;
    u - ((u - reference) / w).round() * w
}

/// The motion direction of a drag from `a` to `b` (panorama pixels, u continuous), in
/// scene.yaml's convention (0 = towards +u, 90 = up), rounded to 0.1°; None for a drag
/// too short to have one.
pub fn direction_of_drag(a: DVec2, b: DVec2) -> Option<f64> {
    let d = b - a;
    if d.length() < 2.0 {
        return None;
    }
    let degrees = ((-d.y).atan2(d.x).to_degrees() * 10.0).round() / 10.0;
    // In (−180, 180], and 0 rather than −0.
    Some(if degrees <= -180.0 {
        degrees + 360.0
    } else {
        degrees + 0.0
    })
}

/// The panorama's regions.
#[derive(Clone, Debug, PartialEq)]
pub struct Document {
    pub width: u32,
    pub height: u32,
    /// The editing resolution of masks.
    pub mask_width: u32,
    pub mask_height: u32,
    pub regions: Vec<Region>,
}

/// Mean directions are taken on a grid at most this wide.
const MEAN_GRID_WIDTH: u32 = 256;
/// A motion arrow shows the region's motion over the loop, but at least and at most
/// this arc, so that slow and fast motions both read as arrows.
const ARROW_MIN_DEG: f64 = 20.0;
const ARROW_MAX_DEG: f64 = 90.0;

impl Document {
    pub fn new_mask(&self) -> Mask {
        Mask::empty(self.mask_width, self.mask_height)
    }

    /// Whether region `index` covers the pixel centre (u, v).
    pub fn covers(&self, index: usize, u: f64, v: f64) -> bool {
        let (w, h) = (self.width, self.height);
        match &self.regions[index].shape {
            Shape::Box(b) => b.contains(u.rem_euclid(w as f64), v),
            Shape::Click { at, size } => {
                click_box(*at, *size, w, h).contains(u.rem_euclid(w as f64), v)
            }
            Shape::Mask { mask, .. } => mask.at(u, v, w, h),
        }
    }

    /// The topmost (last) region covering (u, v).
    pub fn region_at(&self, u: f64, v: f64) -> Option<usize> {
        (0..self.regions.len())
            .rev()
            .find(|&i| self.covers(i, u, v))
    }

    /// Per pixel of the editing resolution: 1 + the index of the topmost region covering
    /// its centre (255 for the 255th and later), 0 where none does.
    pub fn labels(&self) -> Vec<u8> {
        let (mw, mh) = (self.mask_width as usize, self.mask_height as usize);
        let mut labels = vec![0u8; mw * mh];
        let sx = self.width as f64 / mw as f64;
        let sy = self.height as f64 / mh as f64;
        // The first pixel whose centre (i + 0.5)·scale is at or past `at`.
        let first =
            |at: f64, scale: f64, n: usize| ((at / scale - 0.5).ceil().max(0.0) as usize).min(n);
        for (index, region) in self.regions.iter().enumerate() {
            let label = (index + 1).min(255) as u8;
            let b = match &region.shape {
                Shape::Box(b) => *b,
                Shape::Click { at, size } => click_box(*at, *size, self.width, self.height),
                Shape::Mask { mask, .. }
                    if (mask.width, mask.height) == (self.mask_width, self.mask_height) =>
                {
                    for (out, &m) in labels.iter_mut().zip(&mask.pixels) {
                        if m != 0 {
                            *out = label;
                        }
                    }
                    continue;
                }
                Shape::Mask { .. } => {
                    for y in 0..mh {
                        let v = (y as f64 + 0.5) * sy;
                        for x in 0..mw {
                            if self.covers(index, (x as f64 + 0.5) * sx, v) {
                                labels[y * mw + x] = label;
                            }
                        }
                    }
                    continue;
                }
            };
            // A box is a run of rows, each one run of columns (two across the seam).
            let (x0, x1) = (first(b.u0, sx, mw), first(b.u1, sx, mw));
            let runs = if b.wraps() {
                [(x0, mw), (0, x1)]
            } else {
                [(x0, x1), (0, 0)]
            };
            for y in first(b.v0, sy, mh)..first(b.v1, sy, mh) {
                for (start, end) in runs {
                    labels[y * mw + start..y * mw + end.max(start)].fill(label);
                }
            }
        }
        labels
    }

    /// The area-weighted sum of the directions region `index` covers (zero if none).
    pub fn direction_sum(&self, index: usize) -> DVec3 {
        let gw = MEAN_GRID_WIDTH.min(self.width);
        let gh = gw / 2;
        let (sx, sy) = (
            self.width as f64 / gw as f64,
            self.height as f64 / gh as f64,
        );
        let mut sum = DVec3::ZERO;
        for y in 0..gh {
            for x in 0..gw {
                let (u, v) = ((x as f64 + 0.5) * sx, (y as f64 + 0.5) * sy);
                if self.covers(index, u, v) {
                    let d = equirect_to_dir(u, v, self.width, self.height);
                    sum += d * d.x.hypot(d.y); // a cell's solid angle ∝ cos(latitude)
                }
            }
        }
        sum
    }

    /// Where region `index`'s arrow starts: a box's centre, the click, a mask's mean
    /// direction.
    pub fn anchor(&self, index: usize) -> DVec2 {
        let (w, h) = (self.width, self.height);
        match &self.regions[index].shape {
            Shape::Box(b) => b.centre(w),
            Shape::Click { at, .. } => *at,
            Shape::Mask { .. } => {
                let sum = self.direction_sum(index);
                if sum.length() < 1e-9 {
                    DVec2::new(w as f64 / 2.0, h as f64 / 2.0)
                } else {
                    dir_to_equirect(sum, w, h)
                }
            }
        }
    }

    /// Region `index`'s rigid rotation Ω in radians per frame, as the animator builds it
    /// (`pano4d.regions.region_angular_velocity`): direction 0 turns about −z
    /// (towards +u), 90 lifts the region's mean azimuth towards the zenith.
    pub fn angular_velocity(&self, index: usize) -> DVec3 {
        let motion = self.regions[index].motion_or_default();
        let (speed, angle) = (motion.speed.to_radians(), motion.direction_deg.to_radians());
        let sum = self.direction_sum(index);
        let mut heading = DVec3::new(sum.x, sum.y, 0.0);
        if heading.length() < 1e-6 * sum.length().max(1e-12) || heading.length() < 1e-12 {
            heading = DVec3::X; // a cap round a pole has no mean azimuth
        }
        let north = heading.normalize().cross(DVec3::Z);
        speed * (angle.cos() * DVec3::NEG_Z + angle.sin() * north)
    }

    /// Region `index`'s arrow: the path of its anchor under its rotation over `frames`
    /// frames (at least ARROW_MIN_DEG, at most ARROW_MAX_DEG of turn), u continuous.
    pub fn motion_path(&self, index: usize, frames: usize, points: usize) -> Vec<DVec2> {
        let omega = self.angular_velocity(index);
        let rate = omega.length();
        if rate < 1e-12 {
            return Vec::new();
        }
        let turn =
            (rate * frames as f64).clamp(ARROW_MIN_DEG.to_radians(), ARROW_MAX_DEG.to_radians());
        let start = self.anchor(index);
        let d0 = equirect_to_dir(start.x, start.y, self.width, self.height);
        let mut path = vec![start];
        for k in 1..=points {
            let q = DQuat::from_axis_angle(omega / rate, turn * k as f64 / points as f64);
            let uv = dir_to_equirect(q * d0, self.width, self.height);
            let previous = path.last().expect("starts with the anchor").x;
            path.push(DVec2::new(unwrap_near(uv.x, previous, self.width), uv.y));
        }
        path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u32 = 512;
    const H: u32 = 256;

    #[test]
    fn a_drag_across_the_seam_is_one_wrapping_box() {
        let b = PixelBox::from_corners(DVec2::new(492.3, 100.0), DVec2::new(531.6, 140.2), W, H)
            .unwrap();
        assert_eq!(
            b,
            PixelBox {
                u0: 492.0,
                v0: 100.0,
                u1: 20.0,
                v1: 140.0
            }
        );
        assert!(b.wraps());
        assert_eq!(b.span(W), 40.0);
        assert!(b.contains(511.5, 120.0) && b.contains(0.5, 120.0) && b.contains(19.5, 120.0));
        assert!(!b.contains(20.5, 120.0) && !b.contains(491.5, 120.0));
        assert_eq!(b.centre(W), DVec2::new(0.0, 120.0));
        // Dragged the other way, and to the left of 0: the same box.
        let c = PixelBox::from_corners(DVec2::new(20.0, 140.0), DVec2::new(-20.0, 100.0), W, H);
        assert_eq!(c, Some(b));
        // Ending on the seam is not a wrap; over the whole width is the whole width.
        let edge = PixelBox::from_corners(DVec2::new(400.0, 0.0), DVec2::new(512.0, 9.0), W, H);
        assert_eq!(edge.unwrap().u1, 512.0);
        let all = PixelBox::from_corners(DVec2::new(-300.0, 0.0), DVec2::new(300.0, 9.0), W, H);
        assert_eq!(
            all.unwrap(),
            PixelBox {
                u0: 0.0,
                v0: 0.0,
                u1: 512.0,
                v1: 9.0
            }
        );
        // A click is not a box.
        assert_eq!(
            PixelBox::from_corners(DVec2::new(5.0, 5.0), DVec2::new(5.2, 80.0), W, H),
            None
        );
    }

    #[test]
    fn click_boxes_follow_python() {
        // tests/test_config.py: click [5, 100] size 16 on 512×256 → (509, 92, 13, 108).
        let b = click_box(DVec2::new(5.0, 100.0), 16.0, W, H);
        assert_eq!(
            b,
            PixelBox {
                u0: 509.0,
                v0: 92.0,
                u1: 13.0,
                v1: 108.0
            }
        );
        assert_eq!(click_box(DVec2::new(5.0, 3.0), 600.0, W, H).span(W), 512.0);
    }

    /// Brute force: every pixel centre whose direction is within `radius` of `centre`.
    fn brute_cap(centre: DVec3, radius: f64, w: u32, h: u32) -> Vec<Option<bool>> {
        let c = centre.normalize();
        let mut out = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let d = equirect_to_dir(x as f64 + 0.5, y as f64 + 0.5, w, h);
                let margin = d.dot(c) - radius.cos();
                // Pixels within rounding of the rim may go either way.
                out.push((margin.abs() > 1e-9).then_some(margin > 0.0));
            }
        }
        out
    }

    #[test]
    fn brush_caps_match_the_sphere_at_the_seam_and_the_poles() {
        let cases = [
            (equirect_to_dir(3.0, 128.0, W, H), 0.1),  // on the seam
            (equirect_to_dir(300.0, 4.0, W, H), 0.08), // touching the north pole
            (DVec3::new(0.2, -0.1, -1.0), 0.3),        // over the south pole
            (DVec3::new(1.0, 1.0, 0.3), 0.02),         // small, mid-latitude
            (DVec3::Z, 0.05),                          // centred on the pole
        ];
        for (centre, radius) in cases {
            let mut mask = Mask::empty(W, H);
            mask.paint_cap(centre, radius, true);
            let expected = brute_cap(centre, radius, W, H);
            let wrong = mask
                .pixels
                .iter()
                .zip(&expected)
                .filter(|(&m, e)| e.is_some_and(|e| e != (m != 0)))
                .count();
            assert_eq!(wrong, 0, "cap {centre:?} r {radius}");
            assert!(mask.count() > 0);
            mask.paint_cap(centre, radius * 1.01, false);
            assert_eq!(mask.count(), 0, "erasing a slightly larger cap clears it");
        }
        // A cap over a pole covers the top rows whole.
        let mut cap = Mask::empty(W, H);
        cap.paint_cap(equirect_to_dir(300.0, 4.0, W, H), 0.08, true);
        assert!((0..W).all(|x| cap.get(x, 0)));
    }

    fn document(regions: Vec<Region>) -> Document {
        Document {
            width: W,
            height: H,
            mask_width: W / 2,
            mask_height: H / 2,
            regions,
        }
    }

    fn boxed(b: PixelBox, motion: Option<Motion>) -> Region {
        Region {
            name: None,
            shape: Shape::Box(b),
            motion,
        }
    }

    #[test]
    fn labels_and_hits_take_the_topmost_region() {
        let under = boxed(
            PixelBox {
                u0: 0.0,
                v0: 0.0,
                u1: 100.0,
                v1: 100.0,
            },
            None,
        );
        let over = boxed(
            PixelBox {
                u0: 500.0,
                v0: 50.0,
                u1: 50.0,
                v1: 60.0,
            },
            None,
        );
        let doc = document(vec![under, over]);
        assert_eq!(doc.region_at(10.5, 10.5), Some(0));
        assert_eq!(doc.region_at(10.5, 55.5), Some(1));
        assert_eq!(doc.region_at(505.5, 55.5), Some(1));
        assert_eq!(doc.region_at(200.5, 55.5), None);
        let labels = doc.labels();
        let at = |u: f64, v: f64| labels[(v / 2.0) as usize * 256 + (u / 2.0) as usize];
        assert_eq!(
            (
                at(10.0, 10.0),
                at(10.0, 55.0),
                at(505.0, 55.0),
                at(200.0, 55.0)
            ),
            (1, 2, 2, 0)
        );
    }

    #[test]
    fn labels_match_the_per_pixel_rule() {
        let shapes = [
            Shape::Box(PixelBox {
                u0: 10.3,
                v0: 0.0,
                u1: 200.7,
                v1: 33.5,
            }),
            Shape::Box(PixelBox {
                u0: 480.0,
                v0: 100.0,
                u1: 21.0,
                v1: 256.0,
            }),
            Shape::Box(PixelBox {
                u0: 0.0,
                v0: 7.0,
                u1: 512.0,
                v1: 9.0,
            }),
            Shape::Click {
                at: DVec2::new(3.0, 250.0),
                size: 40.0,
            },
        ];
        for shape in shapes {
            let doc = document(vec![Region {
                name: None,
                shape,
                motion: None,
            }]);
            let labels = doc.labels();
            for y in 0..doc.mask_height {
                for x in 0..doc.mask_width {
                    let (u, v) = ((x as f64 + 0.5) * 2.0, (y as f64 + 0.5) * 2.0);
                    let expected = doc.covers(0, u, v) as u8;
                    assert_eq!(
                        labels[(y * doc.mask_width + x) as usize],
                        expected,
                        "{:?} at {x}, {y}",
                        doc.regions[0]
                    );
                }
            }
        }
    }

    #[test]
    fn arrows_follow_the_animators_rotation() {
        let b = PixelBox {
            u0: 100.0,
            v0: 100.0,
            u1: 140.0,
            v1: 140.0,
        };
        let right = document(vec![boxed(
            b,
            Some(Motion {
                direction_deg: 0.0,
                speed: 2.0,
            }),
        )]);
        // 14 frames at 2°/frame: 28° of turn.
        let path = right.motion_path(0, 14, 8);
        let end = *path.last().unwrap();
        assert!(
            (end.y - 120.0).abs() < 1e-6,
            "direction 0 stays on its row: {end:?}"
        );
        assert!(
            (end.x - (120.0 + 28.0 * W as f64 / 360.0)).abs() < 1e-6,
            "{end:?}"
        );
        let up = document(vec![boxed(
            b,
            Some(Motion {
                direction_deg: 90.0,
                speed: 2.0,
            }),
        )]);
        let end = *up.motion_path(0, 14, 8).last().unwrap();
        assert!(
            (end.x - 120.0).abs() < 1e-6
                && (end.y - (120.0 - 28.0 * H as f64 / 180.0)).abs() < 1e-6,
            "direction 90 rises: {end:?}"
        );
        // The drawn direction is the drag's, in the image.
        let a = DVec2::new(10.0, 10.0);
        assert_eq!(
            direction_of_drag(a, a + DVec2::new(10.0, -10.0)),
            Some(45.0)
        );
        assert_eq!(
            direction_of_drag(a, a + DVec2::new(-10.0, 0.0)),
            Some(180.0)
        );
        assert_eq!(direction_of_drag(a, a + DVec2::new(1.0, 0.0)), None);
    }

    #[test]
    fn masks_compare_by_identity_and_round_trip_through_png() {
        let mut mask = Mask::empty(64, 32);
        mask.paint_cap(DVec3::X, 0.3, true);
        let shared = Arc::new(mask.clone());
        let a = Shape::Mask {
            mask: shared.clone(),
            file: None,
        };
        assert_eq!(
            a,
            Shape::Mask {
                mask: shared,
                file: None
            }
        );
        assert_ne!(
            a,
            Shape::Mask {
                mask: Arc::new(mask.clone()),
                file: None
            }
        );
        let path = std::env::temp_dir().join(format!("pano4d-mask-{}.png", std::process::id()));
        mask.save_png(&path).unwrap();
        assert_eq!(Mask::from_png(&path).unwrap(), mask);
        std::fs::remove_file(path).unwrap();
    }
}
