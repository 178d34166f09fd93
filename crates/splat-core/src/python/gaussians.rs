//! `GaussianArrays`: the one form in which a Gaussian set crosses between Python and Rust
//! (rendering, training, `.ply` and `.ply4d`), and gradients or Adam moments of one, which
//! have the same shapes.
//!
//! Built by keyword from float32 numpy arrays with the shapes of `pano4d.gaussians.Gaussians`
//! (means (N, 3), log_scales (N, 3), quats (N, 4), opacity_logits (N,), sh (N, K, 3)) and
//! read back by name; `pano4d.extension` converts it to and from `Gaussians`.

use numpy::prelude::*;
use numpy::{PyArray1, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::gaussians::{sh_coeffs, GaussianSet, SceneInput};

/// N Gaussians in the 3DGS parameterisation, held by the extension (a [`GaussianSet`]).
#[pyclass(name = "GaussianArrays", module = "pano4d._core", frozen)]
pub struct PyGaussianArrays {
    set: GaussianSet,
}

impl PyGaussianArrays {
    /// The arrays as the renderer and the training session borrow them.
    pub(super) fn input(&self) -> SceneInput<'_> {
        SceneInput::from(&self.set)
    }

    pub(super) fn set(&self) -> &GaussianSet {
        &self.set
    }

    /// `n` Gaussians of `sh_degree` in [`SceneInput::packed`]'s layout.
    pub(super) fn from_packed(packed: &[f32], n: usize, sh_degree: u32) -> Self {
        GaussianSet::from_packed(packed, n, sh_degree).into()
    }
}

impl From<GaussianSet> for PyGaussianArrays {
    fn from(set: GaussianSet) -> Self {
        Self { set }
    }
}

/// The values of `array` in row-major order, after checking its shape against `shape`
/// (None: any length), with its shape.
fn values(
    name: &str,
    array: &PyReadonlyArrayDyn<'_, f32>,
    shape: &[Option<usize>],
) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let got = array.shape();
    let matches = got.len() == shape.len()
        && got
            .iter()
            .zip(shape)
            .all(|(g, w)| w.is_none_or(|w| w == *g));
    if !matches {
        return Err(PyValueError::new_err(format!(
            "'{name}' has shape {got:?}, expected {shape:?} (None = any)"
        )));
    }
    Ok((got.to_vec(), array.as_array().iter().copied().collect()))
}

/// A numpy array of `shape` holding `data`.
fn shaped<'py>(
    py: Python<'py>,
    data: Vec<f32>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    PyArray1::from_vec(py, data).reshape(shape)
}

#[pymethods]
impl PyGaussianArrays {
    /// Float32 arrays of any memory layout; `sh` has K = (degree + 1)² coefficients per
    /// channel for a degree in 0..=3. The values are copied.
    #[new]
    #[pyo3(signature = (*, means, log_scales, quats, opacity_logits, sh))]
    fn new(
        means: PyReadonlyArrayDyn<'_, f32>,
        log_scales: PyReadonlyArrayDyn<'_, f32>,
        quats: PyReadonlyArrayDyn<'_, f32>,
        opacity_logits: PyReadonlyArrayDyn<'_, f32>,
        sh: PyReadonlyArrayDyn<'_, f32>,
    ) -> PyResult<Self> {
        let (means_shape, means) = values("means", &means, &[None, Some(3)])?;
        let n = means_shape[0];
        let (sh_shape, sh) = values("sh", &sh, &[Some(n), None, Some(3)])?;
        let k = sh_shape[1];
        let Some(sh_degree) = (0..=3).find(|&d| sh_coeffs(d) == k) else {
            return Err(PyValueError::new_err(format!(
                "'sh' has {k} coefficients per channel, not (degree + 1)^2 for degree 0..3"
            )));
        };
        let triples = |v: Vec<f32>| -> Vec<[f32; 3]> {
            v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
        };
        let (_, log_scales) = values("log_scales", &log_scales, &[Some(n), Some(3)])?;
        let (_, quats) = values("quats", &quats, &[Some(n), Some(4)])?;
        let (_, opacity_logits) = values("opacity_logits", &opacity_logits, &[Some(n)])?;
        Ok(Self {
            set: GaussianSet {
                sh_degree,
                means: triples(means),
                log_scales: triples(log_scales),
                quats: quats
                    .chunks_exact(4)
                    .map(|c| [c[0], c[1], c[2], c[3]])
                    .collect(),
                opacity_logits,
                sh,
            },
        })
    }

    /// (N, 3)
    #[getter]
    fn means<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        shaped(
            py,
            self.set.means.as_flattened().to_vec(),
            &[self.set.len(), 3],
        )
    }

    /// (N, 3)
    #[getter]
    fn log_scales<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        shaped(
            py,
            self.set.log_scales.as_flattened().to_vec(),
            &[self.set.len(), 3],
        )
    }

    /// (N, 4), (w, x, y, z)
    #[getter]
    fn quats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        shaped(
            py,
            self.set.quats.as_flattened().to_vec(),
            &[self.set.len(), 4],
        )
    }

    /// (N,)
    #[getter]
    fn opacity_logits<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        shaped(py, self.set.opacity_logits.clone(), &[self.set.len()])
    }

    /// (N, K, 3)
    #[getter]
    fn sh<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let k = sh_coeffs(self.set.sh_degree);
        shaped(py, self.set.sh.clone(), &[self.set.len(), k, 3])
    }

    #[getter]
    fn sh_degree(&self) -> u32 {
        self.set.sh_degree
    }

    fn __len__(&self) -> usize {
        self.set.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "GaussianArrays(<{} Gaussians of SH degree {}>)",
            self.set.len(),
            self.set.sh_degree
        )
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyGaussianArrays>()
}
