//! A small synthetic 4D scene for tests and the benchmark: a coloured shell of static
//! Gaussians around the origin and a ball of dynamic Gaussians that rises over time in
//! front of the panorama's viewpoint (left of the image centre); and the same as a
//! version-2 scene, whose ball bobs up and down in a loop.

use glam::DVec3;
use splat_core::gaussians::{sh_coeffs, GaussianSet, SH_C0};
use splat_core::ply4d::{CameraInfo, Provenance, Scene4d, SceneMeta, SpacetimeScene4d};
use splat_core::spacetime::{SpacetimeSet, TimeModel};

/// Radius of the static shell.
pub const SHELL_RADIUS: f64 = 5.0;
/// Radius of the moving ball.
pub const BALL_RADIUS: f64 = 0.4;
/// Timestamps per second.
pub const FPS: f64 = 10.0;

/// Centre of the moving ball at timestamp `t` of `times`: it rises from z = -0.8 to +0.8
/// at (3, 1.2), which the panorama's viewpoint sees left of the image centre.
pub fn ball_centre(t: usize, times: usize) -> DVec3 {
    let progress = if times > 1 {
        t as f64 / (times - 1) as f64
    } else {
        0.0
    };
    DVec3::new(3.0, 1.2, -0.8 + 1.6 * progress)
}

/// Deterministic uniform numbers in [0, 1) (SplitMix64).
struct Random(u64);

impl Random {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    fn unit_vector(&mut self) -> DVec3 {
        let z = 2.0 * self.next() - 1.0;
        let a = std::f64::consts::TAU * self.next();
        let r = (1.0 - z * z).sqrt();
        DVec3::new(r * a.cos(), r * a.sin(), z)
    }
}

fn push(set: &mut GaussianSet, mean: DVec3, scale: f64, rgb: [f64; 3], random: &mut Random) {
    set.means.push(mean.as_vec3().to_array());
    set.log_scales.push([scale.ln() as f32; 3]);
    set.quats.push([1.0, 0.0, 0.0, 0.0]);
    set.opacity_logits.push(3.0);
    let k = sh_coeffs(set.sh_degree);
    for c in rgb {
        set.sh.push(((c - 0.5) / SH_C0 as f64) as f32);
    }
    // Small view-dependent terms, so that higher degrees are exercised.
    for _ in 1..k {
        for _ in 0..3 {
            set.sh.push((0.05 * (random.next() - 0.5)) as f32);
        }
    }
}

/// `static_count` Gaussians on the shell, `dynamic_count` in the ball at each of `times`
/// timestamps, SH degree `sh_degree`, the same output for the same `seed`.
pub fn scene(
    static_count: usize,
    dynamic_count: usize,
    times: usize,
    sh_degree: u32,
    seed: u64,
) -> Scene4d {
    let mut random = Random(seed);
    let mut static_set = GaussianSet {
        sh_degree,
        ..Default::default()
    };
    // Splat size that roughly covers the shell at this density.
    let spacing = SHELL_RADIUS * (4.0 * std::f64::consts::PI / static_count.max(1) as f64).sqrt();
    for _ in 0..static_count {
        let d = random.unit_vector();
        // Bands of colour by longitude and latitude, so that any view has structure.
        let lon = d.y.atan2(d.x);
        let rgb = [
            0.5 + 0.4 * (3.0 * lon).sin(),
            0.5 + 0.4 * (4.0 * d.z).cos(),
            0.5 + 0.4 * (2.0 * lon + d.z).cos(),
        ];
        push(
            &mut static_set,
            d * SHELL_RADIUS,
            0.6 * spacing,
            rgb,
            &mut random,
        );
    }
    let ball_spacing = BALL_RADIUS * (dynamic_count.max(1) as f64).powf(-1.0 / 3.0);
    let dynamic = (0..times)
        .map(|t| {
            let mut set = GaussianSet {
                sh_degree,
                ..Default::default()
            };
            let centre = ball_centre(t, times);
            for _ in 0..dynamic_count {
                let offset = random.unit_vector() * BALL_RADIUS * random.next().cbrt();
                let rgb = [0.95, 0.3 + 0.2 * random.next(), 0.1];
                push(
                    &mut set,
                    centre + offset,
                    1.2 * ball_spacing,
                    rgb,
                    &mut random,
                );
            }
            set
        })
        .collect();
    Scene4d {
        static_set,
        dynamic,
        meta: SceneMeta {
            timestamps: (0..times).map(|t| t as f64 / FPS).collect(),
            fps: FPS,
            camera: CameraInfo::default(),
            provenance: Provenance {
                tool_version: format!("pano4d-view {} synthetic", env!("CARGO_PKG_VERSION")),
                config_hash: format!("seed-{seed}"),
            },
            antialiased: false,
            extra: serde_json::Value::Null,
        },
    }
}

/// [`scene`] as a version-2 scene looping over `times` frames: the ball of its first
/// timestamp bobs from z = -0.8 up to +0.8 and back (one position harmonic), its red
/// flickers (one colour harmonic), and each of its Gaussians is fully present at a centre
/// time of its own and fades a little away from it.
pub fn spacetime_scene(
    static_count: usize,
    dynamic_count: usize,
    times: u32,
    sh_degree: u32,
    seed: u64,
) -> SpacetimeScene4d {
    let mut still = scene(static_count, dynamic_count, 1, sh_degree, seed);
    let mut ball = still.dynamic.remove(0);
    let rise = (ball_centre(1, 2).z - ball_centre(0, 2).z) as f32 / 2.0;
    // z(t) = z₀ + rise − rise·cos(2π·t / times): z₀ at frame 0, z₀ + 2·rise half-way.
    for mean in &mut ball.means {
        mean[2] += rise;
    }
    let n = ball.len();
    let model = TimeModel {
        period: times,
        colour_harmonics: 1,
        position_harmonics: 1,
    };
    let period = times as f32;
    still.meta.timestamps = (0..times).map(|t| f64::from(t) / FPS).collect();
    SpacetimeScene4d {
        static_set: still.static_set,
        dynamic: SpacetimeSet {
            model,
            canonical: ball,
            time_centre: (0..n).map(|i| period * i as f32 / n as f32).collect(),
            // Width `times`: half a loop away from its centre, a Gaussian's logit is 1/8 down.
            time_log_width: vec![period.ln(); n],
            // cos₁ (r g b), sin₁ (r g b): red up and down by a tenth.
            colour_terms: (0..n)
                .flat_map(|_| [0.1 / SH_C0, 0.0, 0.0, 0.0, 0.0, 0.0])
                .collect(),
            // cos₁ (x y z), sin₁ (x y z).
            position_terms: (0..n)
                .flat_map(|_| [0.0, 0.0, -rise, 0.0, 0.0, 0.0])
                .collect(),
        },
        meta: still.meta,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spacetime_scene_bobs_its_ball() {
        let a = spacetime_scene(300, 40, 6, 1, 5);
        a.dynamic.check().unwrap();
        assert_eq!(a.meta.timestamps.len(), 6);
        let still = scene(300, 40, 1, 1, 5);
        assert_eq!(a.static_set, still.static_set);
        for (t, z) in [(0.0, -0.8), (3.0, 0.8), (6.0, -0.8)] {
            let ball = a.dynamic.at(t);
            for (moved, m) in ball.means.iter().zip(&still.dynamic[0].means) {
                assert!((moved[2] - m[2] - (z + 0.8)).abs() < 1e-5, "t = {t}");
                assert_eq!(moved[..2], m[..2]);
            }
        }
    }

    #[test]
    fn scene_is_valid_and_deterministic() {
        let a = scene(300, 40, 3, 1, 5);
        assert_eq!(a, scene(300, 40, 3, 1, 5));
        assert_ne!(a.static_set, scene(300, 40, 3, 1, 6).static_set);
        a.static_set.validate().unwrap();
        assert_eq!(a.dynamic.len(), 3);
        for (t, set) in a.dynamic.iter().enumerate() {
            set.validate().unwrap();
            let centre = ball_centre(t, 3);
            for m in &set.means {
                let d = DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64).distance(centre);
                assert!(d <= BALL_RADIUS + 1e-5);
            }
        }
        for m in &a.static_set.means {
            let r = DVec3::new(m[0] as f64, m[1] as f64, m[2] as f64).length();
            assert!((r - SHELL_RADIUS).abs() < 1e-4);
        }
    }
}
