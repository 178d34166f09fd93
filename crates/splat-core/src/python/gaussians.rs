//! `GaussianArrays`: the one form in which a Gaussian set crosses between Python and Rust
//! (rendering, training, `.ply` and `.ply4d`), and gradients or Adam moments of one, which
//! have the same shapes; `SpacetimeArrays`: the one form a spacetime set crosses in (its
//! canonical `GaussianArrays`, time model and time parameters).
//!
//! Built by keyword from float32 numpy arrays with the shapes of `pano4d.gaussians.Gaussians`
//! (means (N, 3), log_scales (N, 3), quats (N, 4), opacity_logits (N,), sh (N, K, 3)) or
//! `pano4d.spacetime.SpacetimeGaussians` and read back by name; `pano4d.extension` converts
//! them to and from `Gaussians` and `SpacetimeGaussians`.

use numpy::prelude::*;
use numpy::{PyArray1, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::gaussians::{sh_coeffs, GaussianSet, SceneInput};
use crate::spacetime::{SpacetimeSet, TimeInput, TimeModel};

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

/// N spacetime Gaussians (canonical parameters, time model, time parameters), held by the
/// extension (a [`SpacetimeSet`]).
#[pyclass(name = "SpacetimeArrays", module = "pano4d._core", frozen)]
pub struct PySpacetimeArrays {
    set: SpacetimeSet,
}

impl PySpacetimeArrays {
    pub(super) fn set(&self) -> &SpacetimeSet {
        &self.set
    }

    /// The canonical Gaussians and the time parameters as the training session borrows
    /// them.
    pub(super) fn input(&self) -> (SceneInput<'_>, TimeInput<'_>) {
        (SceneInput::from(&self.set.canonical), self.set.time_input())
    }
}

impl From<SpacetimeSet> for PySpacetimeArrays {
    fn from(set: SpacetimeSet) -> Self {
        Self { set }
    }
}

/// `value` as a count of the time model, or a ValueError naming `name`.
fn model_count(name: &str, value: i64) -> PyResult<u32> {
    u32::try_from(value).map_err(|_| {
        PyValueError::new_err(format!(
            "'{name}' must be a whole number in 0..2^32, got {value}"
        ))
    })
}

#[pymethods]
impl PySpacetimeArrays {
    /// The time arrays are float32 of any memory layout, with the shapes of
    /// `SpacetimeGaussians`: time_centre and time_log_width (N,), colour_terms
    /// (N, 2·colour_harmonics, 3), position_terms (N, 2·position_harmonics, 3), N the
    /// canonical set's length. The values are copied.
    #[new]
    #[pyo3(signature = (
        *, canonical, period, colour_harmonics, position_harmonics,
        time_centre, time_log_width, colour_terms, position_terms,
    ))]
    #[allow(clippy::too_many_arguments)] // keyword-only, one per field
    fn new(
        canonical: PyRef<'_, PyGaussianArrays>,
        period: i64,
        colour_harmonics: i64,
        position_harmonics: i64,
        time_centre: PyReadonlyArrayDyn<'_, f32>,
        time_log_width: PyReadonlyArrayDyn<'_, f32>,
        colour_terms: PyReadonlyArrayDyn<'_, f32>,
        position_terms: PyReadonlyArrayDyn<'_, f32>,
    ) -> PyResult<Self> {
        let model = TimeModel {
            period: model_count("period", period)?,
            colour_harmonics: model_count("colour_harmonics", colour_harmonics)?,
            position_harmonics: model_count("position_harmonics", position_harmonics)?,
        };
        model.check().map_err(PyValueError::new_err)?;
        let n = canonical.set.len();
        let terms = |h: u32| [Some(n), Some(2 * h as usize), Some(3)];
        let (_, time_centre) = values("time_centre", &time_centre, &[Some(n)])?;
        let (_, time_log_width) = values("time_log_width", &time_log_width, &[Some(n)])?;
        let (_, colour_terms) = values(
            "colour_terms",
            &colour_terms,
            &terms(model.colour_harmonics),
        )?;
        let (_, position_terms) = values(
            "position_terms",
            &position_terms,
            &terms(model.position_harmonics),
        )?;
        Ok(Self {
            set: SpacetimeSet {
                model,
                canonical: canonical.set.clone(),
                time_centre,
                time_log_width,
                colour_terms,
                position_terms,
            },
        })
    }

    /// The Gaussians at no displacement and full presence.
    #[getter]
    fn canonical(&self) -> PyGaussianArrays {
        self.set.canonical.clone().into()
    }

    /// Frames per loop.
    #[getter]
    fn period(&self) -> u32 {
        self.set.model.period
    }

    #[getter]
    fn colour_harmonics(&self) -> u32 {
        self.set.model.colour_harmonics
    }

    #[getter]
    fn position_harmonics(&self) -> u32 {
        self.set.model.position_harmonics
    }

    /// (N,)
    #[getter]
    fn time_centre<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        shaped(py, self.set.time_centre.clone(), &[self.set.len()])
    }

    /// (N,)
    #[getter]
    fn time_log_width<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        shaped(py, self.set.time_log_width.clone(), &[self.set.len()])
    }

    /// (N, 2·colour_harmonics, 3)
    #[getter]
    fn colour_terms<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let terms = 2 * self.set.model.colour_harmonics as usize;
        shaped(
            py,
            self.set.colour_terms.clone(),
            &[self.set.len(), terms, 3],
        )
    }

    /// (N, 2·position_harmonics, 3)
    #[getter]
    fn position_terms<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let terms = 2 * self.set.model.position_harmonics as usize;
        shaped(
            py,
            self.set.position_terms.clone(),
            &[self.set.len(), terms, 3],
        )
    }

    fn __len__(&self) -> usize {
        self.set.len()
    }

    fn __repr__(&self) -> String {
        let m = &self.set.model;
        format!(
            "SpacetimeArrays(<{} Gaussians of SH degree {}, period {}, harmonics colour {} \
             position {}>)",
            self.set.len(),
            self.set.canonical.sh_degree,
            m.period,
            m.colour_harmonics,
            m.position_harmonics
        )
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyGaussianArrays>()?;
    m.add_class::<PySpacetimeArrays>()
}
