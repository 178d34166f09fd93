//! Spacetime Gaussians: one dynamic set for every time of a looping animation, each
//! Gaussian with canonical 3DGS parameters and a compact function of time (Fourier terms of
//! its SH DC colour and its mean, an opacity that rises and falls around a centre time).
//!
//! The definition and its reference are Python's `pano4d.spacetime` (torch); docs/ply4d.md
//! ("Version 2") states it. Here: the CPU form the `.ply4d` reader uses
//! ([`SpacetimeSet::at`]), tested against the torch one (tests/test_spacetime.py); the GPU
//! form, the evaluate pass (`evaluate`, with its adjoint: the training session launches
//! both), tested against the CPU form; and [`GpuSpacetimeSet`], a set kept on the GPU and
//! evaluated there at any time (the viewer's version-2 playback).

pub(crate) mod evaluate;
mod gpu_set;

pub use gpu_set::GpuSpacetimeSet;

use crate::gaussians::{sh_coeffs, GaussianSet, SceneInput};

/// Most Fourier terms a time model may have per quantity (a hostile file's bound).
pub const MAX_HARMONICS: u32 = 8;

/// The narrowest presence the trainers let a Gaussian have, in frames: the resident
/// trainer's Adam holds each log-width at ≥ ln(MIN_WIDTH_FRAMES) (train/adam.wgsl).
/// Mirrors `pano4d.spacetime.MIN_WIDTH_FRAMES`, the torch trainer's (the trainers' equality
/// test in tests/test_spacetime_train.py starts Gaussians below it in both).
pub const MIN_WIDTH_FRAMES: f32 = 1.5;

/// The form of every Gaussian's function of time in one scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TimeModel {
    /// Frames per loop: frame `period` is frame 0.
    pub period: u32,
    /// Fourier terms of the SH DC colour.
    pub colour_harmonics: u32,
    /// Fourier terms of the mean.
    pub position_harmonics: u32,
}

impl TimeModel {
    /// Why this model cannot be, if it cannot.
    pub fn check(&self) -> Result<(), String> {
        if self.period < 1 {
            return Err(format!(
                "a loop's period must be ≥ 1 frame, got {}",
                self.period
            ));
        }
        for (name, h) in [
            ("colour_harmonics", self.colour_harmonics),
            ("position_harmonics", self.position_harmonics),
        ] {
            if h > MAX_HARMONICS {
                return Err(format!("{name} must be 0..={MAX_HARMONICS}, got {h}"));
            }
        }
        Ok(())
    }

    /// Time parameters per Gaussian: its centre time and log-width, then three values
    /// (x, y, z or r, g, b) per Fourier term of its colour and of its mean.
    pub fn floats_per_gaussian(&self) -> usize {
        2 + 6 * (self.colour_harmonics + self.position_harmonics) as usize
    }

    /// cos(h·u), sin(h·u) for h = 1..=harmonics (cos₁, sin₁, cos₂, …), u = 2π·t / period,
    /// computed in f64 as the torch form is.
    pub fn basis(&self, t: f64, harmonics: u32) -> Vec<f32> {
        let period = f64::from(self.period);
        let u = std::f64::consts::TAU * t.rem_euclid(period) / period;
        (1..=harmonics)
            .flat_map(|h| {
                let (sin, cos) = (f64::from(h) * u).sin_cos();
                [cos as f32, sin as f32]
            })
            .collect()
    }

    /// Signed distance in frames from `centre` to `t` around the loop, in [−period/2,
    /// period/2), in f32 as the torch form computes it.
    pub fn distance(&self, t: f32, centre: f32) -> f32 {
        let period = self.period as f32;
        let d = t - centre;
        d - period * (d / period + 0.5).floor()
    }
}

/// N Gaussians with their functions of time ([`TimeModel`]).
///
/// `colour_terms` is `(N, 2·colour_harmonics, 3)` and `position_terms`
/// `(N, 2·position_harmonics, 3)`, row-major, terms in the order cos₁, sin₁, cos₂, ….
#[derive(Clone, Debug, PartialEq)]
pub struct SpacetimeSet {
    pub model: TimeModel,
    /// The Gaussians at no displacement and full presence.
    pub canonical: GaussianSet,
    /// τ, in frames.
    pub time_centre: Vec<f32>,
    /// log s, s the width in frames of the Gaussian's presence around τ.
    pub time_log_width: Vec<f32>,
    pub colour_terms: Vec<f32>,
    pub position_terms: Vec<f32>,
}

impl SpacetimeSet {
    pub fn len(&self) -> usize {
        self.canonical.len()
    }

    pub fn is_empty(&self) -> bool {
        self.canonical.is_empty()
    }

    /// Why the arrays do not fit together, if they do not.
    pub fn check(&self) -> Result<(), String> {
        self.time_input().check(self.len())
    }

    /// `n` Gaussians of `sh_degree` and `model` from their packed parameters: the
    /// canonical Gaussians as [`crate::gaussians::SceneInput::packed`], then the time
    /// sections in [`TimeInput::sections`]' order (a training session's layout).
    pub fn from_packed(packed: &[f32], n: usize, sh_degree: u32, model: TimeModel) -> Self {
        let (canonical, time) = packed.split_at(packed.len() - n * model.floats_per_gaussian());
        let (time_centre, rest) = time.split_at(n);
        let (time_log_width, rest) = rest.split_at(n);
        let (colour_terms, position_terms) = rest.split_at(n * 6 * model.colour_harmonics as usize);
        Self {
            model,
            canonical: GaussianSet::from_packed(canonical, n, sh_degree),
            time_centre: time_centre.to_vec(),
            time_log_width: time_log_width.to_vec(),
            colour_terms: colour_terms.to_vec(),
            position_terms: position_terms.to_vec(),
        }
    }

    /// The time parameters, borrowed.
    pub fn time_input(&self) -> TimeInput<'_> {
        TimeInput {
            model: self.model,
            time_centre: &self.time_centre,
            time_log_width: &self.time_log_width,
            colour_terms: &self.colour_terms,
            position_terms: &self.position_terms,
        }
    }

    /// The Gaussians at time `t` (frames; any real value, taken modulo the period).
    pub fn at(&self, t: f64) -> GaussianSet {
        let m = &self.model;
        let mut g = self.canonical.clone();
        let k = sh_coeffs(g.sh_degree);
        let colour = m.basis(t, m.colour_harmonics);
        let position = m.basis(t, m.position_harmonics);
        for n in 0..self.len() {
            for c in 0..3 {
                let dc = &mut g.sh[n * k * 3 + c];
                for (j, w) in colour.iter().enumerate() {
                    *dc += w * self.colour_terms[(n * colour.len() + j) * 3 + c];
                }
                let mean = &mut g.means[n][c];
                for (j, w) in position.iter().enumerate() {
                    *mean += w * self.position_terms[(n * position.len() + j) * 3 + c];
                }
            }
            let z = m.distance(t as f32, self.time_centre[n]) * (-self.time_log_width[n]).exp();
            g.opacity_logits[n] -= 0.5 * z * z;
        }
        g
    }
}

/// The evaluate pass's kernel module (for the checks of the WGSL against the Rust structs).
#[cfg(test)]
pub(crate) fn kernel_modules() -> Vec<crate::wgsl::KernelModule> {
    vec![evaluate::module()]
}

/// A set's parameters as a training session and the evaluate pass lay them out: its
/// Gaussians packed ([`SceneInput::packed`]), then a spacetime set's time sections
/// ([`TimeInput::sections`]); [`SpacetimeSet::from_packed`] reads them back.
pub fn packed_parameters(gaussians: &SceneInput<'_>, time: Option<TimeInput<'_>>) -> Vec<f32> {
    let mut packed = gaussians.packed();
    for section in time.iter().flat_map(|t| t.sections()) {
        packed.extend_from_slice(section);
    }
    packed
}

/// A spacetime set's time parameters, borrowed (its canonical Gaussians borrow as a
/// [`crate::gaussians::SceneInput`]): what a training session takes of one.
#[derive(Clone, Copy, Debug)]
pub struct TimeInput<'a> {
    pub model: TimeModel,
    pub time_centre: &'a [f32],
    pub time_log_width: &'a [f32],
    pub colour_terms: &'a [f32],
    pub position_terms: &'a [f32],
}

impl TimeInput<'_> {
    /// The arrays in the order of a trained set's time sections (after its Gaussians'):
    /// centres, log-widths, colour terms, position terms.
    pub fn sections(&self) -> [&[f32]; 4] {
        [
            self.time_centre,
            self.time_log_width,
            self.colour_terms,
            self.position_terms,
        ]
    }

    /// Why these are not the time parameters of `n` Gaussians, if they are not.
    pub fn check(&self, n: usize) -> Result<(), String> {
        let m = &self.model;
        m.check()?;
        for (name, got, want) in [
            ("time_centre", self.time_centre.len(), n),
            ("time_log_width", self.time_log_width.len(), n),
            (
                "colour_terms",
                self.colour_terms.len(),
                n * 6 * m.colour_harmonics as usize,
            ),
            (
                "position_terms",
                self.position_terms.len(),
                n * 6 * m.position_harmonics as usize,
            ),
        ] {
            if got != want {
                return Err(format!(
                    "spacetime set of {n} Gaussians: {name} has {got} values, expected {want}"
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One Gaussian of SH degree 0 with every time term set, centred at `centre`.
    fn one(model: TimeModel, centre: f32) -> SpacetimeSet {
        let terms = |h: u32| (0..6 * h).map(|i| 0.1 * i as f32 - 0.4).collect();
        SpacetimeSet {
            model,
            canonical: GaussianSet {
                sh_degree: 0,
                means: vec![[1.0, -2.0, 0.5]],
                log_scales: vec![[0.0; 3]],
                quats: vec![[1.0, 0.0, 0.0, 0.0]],
                opacity_logits: vec![2.0],
                sh: vec![0.1, 0.2, 0.3],
            },
            time_centre: vec![centre],
            time_log_width: vec![0.5],
            colour_terms: terms(model.colour_harmonics),
            position_terms: terms(model.position_harmonics),
        }
    }

    #[test]
    fn the_loop_closes() {
        let model = TimeModel {
            period: 6,
            colour_harmonics: 2,
            position_harmonics: 1,
        };
        for centre in [0.0, 3.0, 5.5, -7.0] {
            let set = one(model, centre);
            for t in [0.0, 1.0, 2.5, 5.0] {
                let (a, b, c) = (set.at(t), set.at(t + 6.0), set.at(t - 12.0));
                for other in [&b, &c] {
                    assert_eq!(a.sh, other.sh, "t = {t}");
                    assert_eq!(a.means, other.means, "t = {t}");
                    let (x, y) = (a.opacity_logits[0], other.opacity_logits[0]);
                    assert!((x - y).abs() <= 1e-5 * x.abs().max(1.0), "t = {t}: {x} {y}");
                }
            }
        }
    }

    #[test]
    fn distance_is_the_shorter_way_round_the_loop() {
        let model = TimeModel {
            period: 8,
            colour_harmonics: 0,
            position_harmonics: 0,
        };
        for (t, centre, d) in [
            (1.0, 0.0, 1.0),
            (7.0, 0.0, -1.0),
            (0.0, 7.5, 0.5),
            (4.0, 0.0, -4.0),
        ] {
            assert_eq!(model.distance(t, centre), d, "t = {t}, centre {centre}");
        }
    }
}
