//! Kochanek–Bartels splines, the curves nerfstudio's viewer draws a camera path with
//! (render_panel.py, through the `splines` package, 0.3): tension 0.5, continuity 0, bias 0,
//! "natural" ends (no loop), the keyframes at parameters 0, 1, …, n − 1 (every transition the
//! same duration). Numbers (a position's coordinates, a field of view, a time) follow a
//! cubic Hermite curve; rotations, as unit quaternions, the "Kochanek–Bartels-like"
//! rotation spline: cubic Bézier segments evaluated by De Casteljau's algorithm with slerp.
//!
//! Both pass through every keyframe exactly and are C¹ there; the rotation spline stays on
//! the unit sphere and takes the shorter way between keyframes (they are canonicalised:
//! each flipped to the sign nearer its predecessor).

use glam::{DQuat, DVec3};

/// nerfstudio's spline tension.
pub const TENSION: f64 = 0.5;

/// The segment holding parameter `s` (clamped to [0, n − 1]) of a spline through `n` ≥ 2
/// keyframes, and where in it `s` lies, in [0, 1].
fn segment(n: usize, s: f64) -> (usize, f64) {
    let s = s.clamp(0.0, (n - 1) as f64);
    let index = (s.floor() as usize).min(n - 2);
    (index, s - index as f64)
}

/// A Kochanek–Bartels spline through numbers. Interpolating each coordinate of a vector
/// with its own spline is the vector spline: every step is linear in the values.
#[derive(Clone, Debug, PartialEq)]
pub struct Spline {
    values: Vec<f64>,
}

impl Spline {
    /// The spline through `values` (at least two) at 0, 1, …, n − 1.
    pub fn new(values: Vec<f64>) -> Self {
        assert!(values.len() >= 2, "a spline needs two values");
        Self { values }
    }

    /// The value at parameter `s`, clamped to [0, n − 1].
    pub fn at(&self, s: f64) -> f64 {
        let (i, u) = segment(self.values.len(), s);
        let (x0, x1) = (self.values[i], self.values[i + 1]);
        let (v0, v1) = (self.tangent(i), self.tangent(i + 1));
        let u2 = u * u;
        let u3 = u2 * u;
        (2.0 * u3 - 3.0 * u2 + 1.0) * x0
            + (u3 - 2.0 * u2 + u) * v0
            + (3.0 * u2 - 2.0 * u3) * x1
            + (u3 - u2) * v1
    }

    /// The curve's derivative at keyframe `k`: Kochanek–Bartels' inside, and at an end the
    /// one that makes the second derivative vanish there ("natural"). Two keyframes make a
    /// straight segment, run at constant speed.
    fn tangent(&self, k: usize) -> f64 {
        let x = &self.values;
        let n = x.len();
        if n == 2 {
            return x[1] - x[0];
        }
        // Continuity and bias 0: incoming and outgoing tangents agree, (1 − T) × the
        // central difference.
        let inside = |k: usize| (1.0 - TENSION) * (x[k + 1] - x[k - 1]) / 2.0;
        if k == 0 {
            1.5 * (x[1] - x[0]) - inside(1) / 2.0
        } else if k == n - 1 {
            1.5 * (x[n - 1] - x[n - 2]) - inside(n - 2) / 2.0
        } else {
            inside(k)
        }
    }
}

/// The rotation vector (axis × half the angle) of a unit quaternion: the logarithm.
fn log(q: DQuat) -> DVec3 {
    let v = DVec3::new(q.x, q.y, q.z);
    let sin_half = v.length();
    if sin_half < 1e-300 {
        return DVec3::ZERO;
    }
    // atan2 rather than acos: accurate near the identity as well.
    v * (sin_half.atan2(q.w) / sin_half)
}

/// The unit quaternion of a rotation vector (axis × half the angle): the exponential.
fn exp(v: DVec3) -> DQuat {
    let half = v.length();
    if half < 1e-300 {
        return DQuat::IDENTITY;
    }
    let s = half.sin() / half;
    DQuat::from_xyzw(v.x * s, v.y * s, v.z * s, half.cos())
}

/// `q` to the power `t`: the rotation about the same axis by `t` × its angle.
fn pow(q: DQuat, t: f64) -> DQuat {
    exp(log(q) * t)
}

/// Spherical linear interpolation from `a` (t = 0) to `b` (t = 1).
fn slerp(a: DQuat, b: DQuat, t: f64) -> DQuat {
    pow(b * a.conjugate(), t) * a
}

/// A Kochanek–Bartels rotation spline through unit quaternions.
#[derive(Clone, Debug, PartialEq)]
pub struct RotationSpline {
    /// The keyframes, canonicalised.
    rotations: Vec<DQuat>,
}

impl RotationSpline {
    /// The spline through `rotations` (at least two unit quaternions) at 0, 1, …, n − 1.
    pub fn new(rotations: &[DQuat]) -> Self {
        assert!(rotations.len() >= 2, "a spline needs two rotations");
        // q and −q are one rotation; the sign nearer the previous keyframe's makes every
        // relative rotation the shorter one (the first is compared with the identity).
        let mut previous = DQuat::IDENTITY;
        let rotations = rotations
            .iter()
            .map(|&q| {
                let q = if previous.dot(q) < 0.0 { -q } else { q };
                previous = q;
                q
            })
            .collect();
        Self { rotations }
    }

    /// The rotation at parameter `s`, clamped to [0, n − 1].
    pub fn at(&self, s: f64) -> DQuat {
        let (i, u) = segment(self.rotations.len(), s);
        let [a, b, c, d] = self.control_points(i);
        // De Casteljau: three rounds of slerp.
        let (ab, bc, cd) = (slerp(a, b, u), slerp(b, c, u), slerp(c, d, u));
        slerp(slerp(ab, bc, u), slerp(bc, cd, u), u)
    }

    /// The four Bézier control rotations of segment `i` (keyframe `i` to `i + 1`).
    fn control_points(&self, i: usize) -> [DQuat; 4] {
        let q = &self.rotations;
        let n = q.len();
        let (start, end) = (q[i], q[i + 1]);
        if n == 2 {
            // A slerp at constant angular speed.
            let third = pow(end * start.conjugate(), 1.0 / 3.0);
            return [start, third * start, third.conjugate() * end, end];
        }
        // The ends as `splines` 0.3 builds them for "natural": the control next to an end
        // rotation lies halfway from it to its neighbouring keyframe. (The numbers' natural
        // end would aim halfway to the next control instead; kept as `splines` has it, so
        // that orientations match nerfstudio's.)
        let after = if i == 0 {
            slerp(start, end, 0.5)
        } else {
            self.inside_controls(i).1
        };
        let before = if i + 1 == n - 1 {
            slerp(end, start, 0.5)
        } else {
            self.inside_controls(i + 1).0
        };
        [start, after, before, end]
    }

    /// The controls before and after inside keyframe `k`: the rotation vectors to its
    /// neighbours averaged and scaled by (1 − T), a third of it either side, as the numbers'
    /// tangent is.
    fn inside_controls(&self, k: usize) -> (DQuat, DQuat) {
        let q = &self.rotations;
        let incoming = log(q[k] * q[k - 1].conjugate());
        let outgoing = log(q[k + 1] * q[k].conjugate());
        let omega = (1.0 - TENSION) * (incoming + outgoing) / 2.0;
        (exp(-omega / 3.0) * q[k], exp(omega / 3.0) * q[k])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_near(got: f64, want: f64, tolerance: f64) {
        assert!((got - want).abs() <= tolerance, "{got}, not {want}");
    }

    fn axis_angle(axis: [f64; 3], angle: f64) -> DQuat {
        DQuat::from_axis_angle(DVec3::from_array(axis).normalize(), angle)
    }

    /// The angle in radians between two rotations (atan2: accurate for small angles too).
    fn angle_between(a: DQuat, b: DQuat) -> f64 {
        let relative = b * a.conjugate();
        2.0 * relative.xyz().length().atan2(relative.w.abs())
    }

    /// Values from nerfstudio's own interpolator: `splines.KochanekBartels(values,
    /// tcb=(0.5, 0, 0), endconditions="natural").evaluate(s)` (splines 0.3.3).
    #[test]
    fn numbers_match_nerfstudios_spline() {
        let spline = Spline::new(vec![1.0, 4.0, 2.0, 2.5, -1.0]);
        let reference = [
            (0.0, 1.0),
            (0.3, 2.275375),
            (1.0, 4.0),
            (1.5, 3.078125),
            (2.25, 2.060546875),
            (3.7, 0.42537499999999895),
            (4.0, -1.0),
        ];
        for (s, want) in reference {
            assert_near(spline.at(s), want, 1e-12);
        }
        let two = Spline::new(vec![1.0, 4.0]);
        for (s, want) in [(0.0, 1.0), (0.25, 1.75), (0.5, 2.5), (1.0, 4.0)] {
            assert_near(two.at(s), want, 1e-12);
        }
        // Outside [0, n − 1] the ends hold.
        assert_eq!(spline.at(-1.0), 1.0);
        assert_eq!(spline.at(9.0), -1.0);
    }

    /// Values from `splines.quaternion.KochanekBartels(..., tcb=(0.5, 0, 0),
    /// endconditions="natural")` (splines 0.3.3), as xyzw.
    #[test]
    fn rotations_match_nerfstudios_spline() {
        let keyframes = [
            axis_angle([0.0, 0.0, 1.0], 0.2),
            axis_angle([0.0, 0.0, 1.0], 1.4),
            axis_angle([1.0, 0.0, 0.0], 0.5),
            axis_angle([0.3, 1.0, 0.0], -0.8),
        ];
        let spline = RotationSpline::new(&keyframes);
        let reference = [
            (0.0, [0.0, 0.0, 0.09983341664682815, 0.9950041652780258]),
            (
                0.4,
                [
                    -0.006669417399104076,
                    0.0,
                    0.42847086747002994,
                    0.9035309815391152,
                ],
            ),
            (1.0, [0.0, 0.0, 0.644217687237691, 0.7648421872844885]),
            (
                1.5,
                [
                    0.1449806735641782,
                    0.013084711710695373,
                    0.36328957666339967,
                    0.9202337084132775,
                ],
            ),
            (
                2.6,
                [
                    0.09106465344753564,
                    -0.17663447071973748,
                    -0.017213290042141026,
                    0.979903666332545,
                ],
            ),
            (
                3.0,
                [
                    -0.11189853726314196,
                    -0.3729951242104733,
                    0.0,
                    0.921060994002885,
                ],
            ),
        ];
        for (s, want) in reference {
            let got = spline.at(s).to_array();
            for (g, w) in got.iter().zip(want) {
                assert_near(*g, w, 1e-12);
            }
        }
    }

    #[test]
    fn passes_through_every_keyframe() {
        let values = vec![0.5, -2.0, 3.0, 3.0, 7.5, 1.0];
        let spline = Spline::new(values.clone());
        let keyframes: Vec<DQuat> = (0..6)
            .map(|k| axis_angle([1.0, k as f64, 2.0 - k as f64], 0.7 * k as f64 - 1.3))
            .collect();
        let rotations = RotationSpline::new(&keyframes);
        for k in 0..6 {
            assert_eq!(spline.at(k as f64), values[k]);
            assert!(angle_between(rotations.at(k as f64), keyframes[k]) < 1e-12);
        }
    }

    #[test]
    fn two_keyframes_make_a_straight_run_at_constant_speed() {
        let line = Spline::new(vec![2.0, 5.0]);
        for i in 0..=10 {
            let s = i as f64 / 10.0;
            assert_near(line.at(s), 2.0 + 3.0 * s, 1e-12);
        }
        let (a, b) = (
            axis_angle([0.0, 0.0, 1.0], 0.1),
            axis_angle([1.0, 1.0, 0.0], 1.2),
        );
        let turn = RotationSpline::new(&[a, b]);
        let total = angle_between(a, b);
        for i in 0..=10 {
            let s = i as f64 / 10.0;
            assert_near(angle_between(a, turn.at(s)), s * total, 1e-9);
        }
    }

    #[test]
    fn smooth_through_inside_keyframes() {
        let spline = Spline::new(vec![0.0, 1.0, -1.0, 4.0]);
        let h = 1e-6;
        for k in [1.0, 2.0] {
            let left = (spline.at(k) - spline.at(k - h)) / h;
            let right = (spline.at(k + h) - spline.at(k)) / h;
            assert_near(left, right, 1e-4);
        }
    }

    #[test]
    fn nearly_half_turns_stay_unit_and_take_the_shorter_way() {
        let turn = 179.9_f64.to_radians();
        let a = DQuat::IDENTITY;
        let b = axis_angle([0.0, 0.0, 1.0], turn);
        let c = axis_angle([0.0, 0.0, 1.0], 2.0 * turn);
        // The same rotations with the other sign: one curve.
        let flipped = RotationSpline::new(&[a, -b, c]);
        let spline = RotationSpline::new(&[a, b, c]);
        let mut previous = spline.at(0.0);
        let mut turned = 0.0;
        for i in 1..=200 {
            let s = i as f64 / 100.0;
            let q = spline.at(s);
            assert_near(q.length(), 1.0, 1e-12);
            assert!(angle_between(q, flipped.at(s)) < 1e-9);
            // Each step turns about +z, never back (the longer way round is about −z).
            let step = q * previous.conjugate();
            let step = if step.w < 0.0 { -step } else { step };
            assert!(
                step.z >= 0.0 && step.x.abs() < 1e-12 && step.y.abs() < 1e-12,
                "{s}: {step:?}"
            );
            turned += 2.0 * step.z.atan2(step.w);
            previous = q;
        }
        assert_near(turned, 2.0 * turn, 1e-9);
    }
}
