//! The geometry conventions of docs/design.md, mirrored from `python/pano4d/camera.py` and
//! `python/pano4d/sphere.py`. `tests/vectors/geometry.json` (written by Python) keeps
//! the two languages from drifting.
//!
//! World: right-handed, +z up. Equirect W×H (W = 2H), pixel centres at +0.5:
//! φ = 2π(u/W − 0.5), θ = π(0.5 − v/H), d = (cos θ cos φ, −cos θ sin φ, sin θ).
//! Cameras: OpenCV (x right, y down, z forward), world-to-camera [R | t].

use glam::{DMat3, DVec2, DVec3, Mat3, Vec3};
use std::f64::consts::PI;

/// Unit direction for continuous equirect pixel coordinates (u, v).
pub fn equirect_to_dir(u: f64, v: f64, width: u32, height: u32) -> DVec3 {
    let phi = 2.0 * PI * (u / width as f64 - 0.5);
    let theta = PI * (0.5 - v / height as f64);
    DVec3::new(
        theta.cos() * phi.cos(),
        -theta.cos() * phi.sin(),
        theta.sin(),
    )
}

/// Equirect pixel coordinates of a direction (need not be unit length).
/// u is wrapped into [0, W); v is in [0, H].
pub fn dir_to_equirect(d: DVec3, width: u32, height: u32) -> DVec2 {
    let phi = (-d.y).atan2(d.x);
    let theta = d.z.atan2(d.x.hypot(d.y));
    let w = width as f64;
    let mut u = w * (phi / (2.0 * PI) + 0.5);
    u = u.rem_euclid(w);
    if u >= w {
        u = 0.0;
    }
    let v = height as f64 * (0.5 - theta / PI);
    DVec2::new(u, v)
}

/// World-to-camera rotation for a camera looking along `forward` with no roll.
/// Rows are the camera's right, down and forward axes in world coordinates.
/// When `forward` is parallel to `up`, the image top points the way a head tilted back
/// from +x would see it (the same fallback as Python's `look_rotation`).
pub fn look_rotation(forward: DVec3, up: DVec3) -> DMat3 {
    let f = forward.normalize();
    let mut right = f.cross(up);
    if right.length() < 1e-9 * up.length().max(1.0) {
        let fallback = if f.dot(up) < 0.0 {
            DVec3::X
        } else {
            DVec3::NEG_X
        };
        right = f.cross(fallback);
    }
    let right = right.normalize();
    let down = f.cross(right);
    DMat3::from_cols(right, down, f).transpose()
}

/// A pinhole camera: intrinsics in pixels, world-to-camera rotation and translation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// World-to-camera rotation (rows: right, down, forward).
    pub rotation: DMat3,
    pub translation: DVec3,
    pub width: u32,
    pub height: u32,
    /// tan of the half field of view (x, y) of the whole view: what the EWA Jacobian's clamp
    /// reads. A [`Camera::window`] keeps its view's, so that a window renders the view's
    /// pixels, not those of a narrower camera.
    pub half_fov_tan: DVec2,
}

impl Camera {
    /// Horizontal field of view `fov_deg`, square pixels, principal point at the centre.
    pub fn from_fov(
        fov_deg: f64,
        width: u32,
        height: u32,
        position: DVec3,
        forward: DVec3,
        up: DVec3,
    ) -> Self {
        let fx = 0.5 * width as f64 / (fov_deg.to_radians() / 2.0).tan();
        let rotation = look_rotation(forward, up);
        Self {
            fx,
            fy: fx,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
            rotation,
            translation: -(rotation * position),
            width,
            height,
            half_fov_tan: DVec2::new(0.5 * width as f64 / fx, 0.5 * height as f64 / fx),
        }
    }

    /// From row-major K (3×3) and world-to-camera (3×4), as in `views.json`.
    pub fn from_matrices(k: [[f64; 3]; 3], w2c: [[f64; 4]; 3], width: u32, height: u32) -> Self {
        let rotation = DMat3::from_cols_array_2d(&[
            [w2c[0][0], w2c[1][0], w2c[2][0]],
            [w2c[0][1], w2c[1][1], w2c[2][1]],
            [w2c[0][2], w2c[1][2], w2c[2][2]],
        ]);
        Self {
            fx: k[0][0],
            fy: k[1][1],
            cx: k[0][2],
            cy: k[1][2],
            rotation,
            translation: DVec3::new(w2c[0][3], w2c[1][3], w2c[2][3]),
            width,
            height,
            half_fov_tan: DVec2::new(0.5 * width as f64 / k[0][0], 0.5 * height as f64 / k[1][1]),
        }
    }

    /// The `width`×`height` pixels of this camera's image from pixel (`x0`, `y0`) on, as a
    /// camera of their own: the same pixels (the principal point moves, the clamp stays).
    pub fn window(&self, x0: u32, y0: u32, width: u32, height: u32) -> Self {
        Self {
            cx: self.cx - x0 as f64,
            cy: self.cy - y0 as f64,
            width,
            height,
            ..*self
        }
    }

    /// Camera centre in world coordinates.
    pub fn position(&self) -> DVec3 {
        -(self.rotation.transpose() * self.translation)
    }

    pub fn world_to_camera(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    /// Pixel coordinates and z-depth of a world point (pixel is non-finite for z = 0).
    pub fn project(&self, p: DVec3) -> (DVec2, f64) {
        let c = self.world_to_camera(p);
        let uv = DVec2::new(self.fx * c.x / c.z + self.cx, self.fy * c.y / c.z + self.cy);
        (uv, c.z)
    }

    /// World point at pixel `uv` and depth along the camera's z.
    pub fn unproject_z(&self, uv: DVec2, z: f64) -> DVec3 {
        let ray = DVec3::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy, 1.0);
        self.rotation.transpose() * (ray * z - self.translation)
    }

    /// World point at pixel `uv` and distance `ray_length` from the camera centre.
    pub fn unproject_ray(&self, uv: DVec2, ray_length: f64) -> DVec3 {
        let ray = DVec3::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy, 1.0);
        self.unproject_z(uv, ray_length / ray.length())
    }

    /// Rotation and translation in f32, for GPU uniforms.
    pub fn rotation_f32(&self) -> Mat3 {
        self.rotation.as_mat3()
    }

    pub fn translation_f32(&self) -> Vec3 {
        self.translation.as_vec3()
    }
}
