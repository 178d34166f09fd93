//! A CPU-side set of 3D Gaussians in the 3DGS parameterisation.

/// DC term of the real spherical harmonics: colour = 0.5 + SH_C0 * f_dc.
pub const SH_C0: f32 = 0.282_094_8;

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
