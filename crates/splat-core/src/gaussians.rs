//! A CPU-side set of 3D Gaussians in the 3DGS parameterisation.

/// DC term of the real spherical harmonics: colour = 0.5 + SH_C0 * f_dc.
pub const SH_C0: f32 = 0.282_094_8;

/// Floats per Gaussian besides its SH coefficients: mean 3, log-scale 3, quaternion 4,
/// opacity 1.
pub const BASE_FLOATS: usize = 11;

/// Number of SH coefficients per colour channel for `degree` (0..=3).
pub fn sh_coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// N Gaussians, structure of arrays.
///
/// `sh` is coefficient-major per Gaussian: `sh[(n * K + k) * 3 + c]` with
/// `K = sh_coeffs(sh_degree)`, matching Python's `(N, K, 3)` tensor.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GaussianSet {
    pub sh_degree: u32,
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 3]>,
    /// (w, x, y, z), not necessarily normalised: renderers normalise on use.
    pub quats: Vec<[f32; 4]>,
    pub opacity_logits: Vec<f32>,
    pub sh: Vec<f32>,
}

impl GaussianSet {
    /// An empty set of `sh_degree` with room for `n` Gaussians.
    pub fn with_capacity(sh_degree: u32, n: usize) -> Self {
        Self {
            sh_degree,
            means: Vec::with_capacity(n),
            log_scales: Vec::with_capacity(n),
            quats: Vec::with_capacity(n),
            opacity_logits: Vec::with_capacity(n),
            sh: Vec::with_capacity(n * sh_coeffs(sh_degree) * 3),
        }
    }

    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// Appends `other`'s Gaussians (of the same SH degree) after these.
    pub fn extend_from(&mut self, other: &GaussianSet) {
        debug_assert!(other.is_empty() || other.sh_degree == self.sh_degree);
        self.means.extend_from_slice(&other.means);
        self.log_scales.extend_from_slice(&other.log_scales);
        self.quats.extend_from_slice(&other.quats);
        self.opacity_logits.extend_from_slice(&other.opacity_logits);
        self.sh.extend_from_slice(&other.sh);
    }

    /// The inverse of [`SceneInput::packed`]: `n` Gaussians of `sh_degree` from the SoA
    /// sections (means, log-scales, quaternions, opacity logits, SH) laid end to end.
    /// Panics when `packed` is not that long (the caller laid it out).
    pub fn from_packed(packed: &[f32], n: usize, sh_degree: u32) -> Self {
        let k = sh_coeffs(sh_degree);
        assert_eq!(
            packed.len(),
            n * (BASE_FLOATS + 3 * k),
            "packed Gaussians' length"
        );
        let (means, rest) = packed.split_at(3 * n);
        let (log_scales, rest) = rest.split_at(3 * n);
        let (quats, rest) = rest.split_at(4 * n);
        let (opacity_logits, sh) = rest.split_at(n);
        let rows = |values: &[f32]| -> Vec<[f32; 3]> {
            values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
        };
        Self {
            sh_degree,
            means: rows(means),
            log_scales: rows(log_scales),
            quats: quats
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            opacity_logits: opacity_logits.to_vec(),
            sh: sh.to_vec(),
        }
    }

    /// Checks that every array has the length `len()` implies.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.len();
        if self.sh_degree > 3 {
            return Err(format!("SH degree must be 0..=3, got {}", self.sh_degree));
        }
        let k = sh_coeffs(self.sh_degree);
        let checks = [
            ("log_scales", self.log_scales.len(), n),
            ("quats", self.quats.len(), n),
            ("opacity_logits", self.opacity_logits.len(), n),
            ("sh", self.sh.len(), n * k * 3),
        ];
        for (name, got, want) in checks {
            if got != want {
                return Err(format!(
                    "{name} has {got} values, expected {want} for {n} Gaussians"
                ));
            }
        }
        Ok(())
    }
}

/// Gaussians in the 3DGS parameterisation, as borrowed flat f32 slices (row-major arrays):
/// what the rasteriser uploads, from a [`GaussianSet`] or straight from Python's arrays.
#[derive(Clone, Copy, Debug)]
pub struct SceneInput<'a> {
    pub means: &'a [f32],
    pub log_scales: &'a [f32],
    /// (w, x, y, z), normalised on use.
    pub quats: &'a [f32],
    pub opacity_logits: &'a [f32],
    /// `[n][k][3]` with k = (degree + 1)².
    pub sh: &'a [f32],
}

impl<'a> From<&'a GaussianSet> for SceneInput<'a> {
    /// Borrows the set's arrays as they are (no copy).
    fn from(set: &'a GaussianSet) -> Self {
        Self {
            means: set.means.as_flattened(),
            log_scales: set.log_scales.as_flattened(),
            quats: set.quats.as_flattened(),
            opacity_logits: &set.opacity_logits,
            sh: &set.sh,
        }
    }
}

impl SceneInput<'_> {
    pub fn len(&self) -> usize {
        self.opacity_logits.len()
    }

    pub fn is_empty(&self) -> bool {
        self.opacity_logits.is_empty()
    }

    /// Checks the array lengths and returns (n, SH coefficients per channel), or what is
    /// wrong with them.
    pub fn validate(&self) -> Result<(u32, u32), String> {
        let n = self.len();
        let bad = |what: &str, got: usize, want: usize| {
            format!("{what} has {got} values, expected {want} for {n} Gaussians")
        };
        if self.means.len() != 3 * n {
            return Err(bad("means", self.means.len(), 3 * n));
        }
        if self.log_scales.len() != 3 * n {
            return Err(bad("log_scales", self.log_scales.len(), 3 * n));
        }
        if self.quats.len() != 4 * n {
            return Err(bad("quats", self.quats.len(), 4 * n));
        }
        let k = if n == 0 { 1 } else { self.sh.len() / (3 * n) };
        let degree_ok = (0..=3).any(|d| sh_coeffs(d) == k);
        if !degree_ok || self.sh.len() != 3 * k * n {
            return Err(format!(
                "sh has {} values: expected n * k * 3 with k in {{1, 4, 9, 16}} for {n} Gaussians",
                self.sh.len()
            ));
        }
        let n32 = u32::try_from(n)
            .ok()
            .filter(|&v| v < u32::MAX / 64)
            .ok_or_else(|| format!("too many Gaussians: {n}"))?;
        Ok((n32, k as u32))
    }

    /// The parameter arrays in the order of the shaders' SoA sections.
    pub fn sections(&self) -> [&[f32]; 5] {
        [
            self.means,
            self.log_scales,
            self.quats,
            self.opacity_logits,
            self.sh,
        ]
    }

    /// The SoA f32 layout the shaders read: means, log-scales, quats, opacity, SH.
    pub fn packed(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(BASE_FLOATS * self.len() + self.sh.len());
        for part in self.sections() {
            out.extend_from_slice(part);
        }
        out
    }
}
