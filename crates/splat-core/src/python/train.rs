//! Python binding of the resident training loop: `TrainSession` (driven by
//! `pano4d.lift.resident.ResidentTrainer`).
//!
//! Everything crosses as typed objects built by keyword and read by name: the knobs as one
//! `TrainSettings` (the Rust [`TrainConfig`]), each view's targets as a `ViewTarget`, the
//! static set and the scene's gradients as `GaussianArrays`, the trained set and its Adam
//! moments as `GaussianArrays` or, for a spacetime set, `SpacetimeArrays`
//! (python/gaussians.rs; what the session gives back is of the kind it was given), and
//! what comes back as `LossParts`, `FrameCheck`, `TrainState` and `Traffic`. Every call runs on the process-wide renderer (python/raster.rs) with the
//! GIL released.

use std::collections::BTreeMap;

use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::gaussians::{PyGaussianArrays, PySpacetimeArrays};
use super::raster::{render_settings, slice, to_py, with_renderer, PyView};
use crate::gaussians::SceneInput;
use crate::raster::IntersectionCheck;
use crate::spacetime::{packed_parameters, SpacetimeSet, TimeInput};
use crate::train::{
    AdamConfig, LossParts, LossWeights, Traffic, TrainConfig, TrainSession, TrainedInput,
    ViewTargets, GROUPS, OUTSIDE_SUMS,
};

/// The learning-rate groups by name, in [`crate::train::AdamConfig::learning_rates`]' order
/// (GaussianTrainer's parameter groups: means trained as offsets in units of each
/// Gaussian's initial depth, then a spacetime set's time parameters, its position terms
/// in the same units).
const GROUP_NAMES: [&str; GROUPS] = [
    "offsets",
    "log_scales",
    "quats",
    "opacity_logits",
    "sh_dc",
    "sh_rest",
    "colour_terms",
    "position_terms",
    "time_centre",
    "time_log_width",
];

/// What a training session is configured with: Adam's learning rates (by group name), β
/// and ε, the weights of the device's losses, the background and the rasteriser's mode
/// (`antialiased`: the 2D filter with opacity compensation, docs/rasterizer.md). Built by keyword only, read
/// back by name (`TrainSession.settings` returns the session's own).
#[pyclass(name = "TrainSettings", module = "pano4d._core", frozen)]
#[derive(Clone)]
pub struct PyTrainSettings {
    config: TrainConfig,
}

#[pymethods]
impl PyTrainSettings {
    /// `learning_rates`: {group: rate} for exactly the groups offsets, log_scales, quats,
    /// opacity_logits, sh_dc, sh_rest, colour_terms, position_terms, time_centre,
    /// time_log_width (the last four a spacetime set's); `lambda_l1`, `lambda_ssim`, `lambda_temporal`,
    /// `lambda_geo`: the weights of L1, D-SSIM, L_temporal and L_geo; `antialiased`: the
    /// mode every render of the session draws in.
    #[new]
    #[pyo3(signature = (*, learning_rates, betas, eps, lambda_l1, lambda_ssim, lambda_temporal, lambda_geo, background, antialiased))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        learning_rates: BTreeMap<String, f64>,
        betas: (f64, f64),
        eps: f64,
        lambda_l1: f32,
        lambda_ssim: f32,
        lambda_temporal: f32,
        lambda_geo: f32,
        background: [f32; 3],
        antialiased: bool,
    ) -> PyResult<Self> {
        let unknown: Vec<&str> = learning_rates
            .keys()
            .map(String::as_str)
            .filter(|name| !GROUP_NAMES.contains(name))
            .collect();
        let missing: Vec<&str> = GROUP_NAMES
            .into_iter()
            .filter(|name| !learning_rates.contains_key(*name))
            .collect();
        if !unknown.is_empty() || !missing.is_empty() {
            return Err(PyValueError::new_err(format!(
                "learning_rates needs exactly the groups {GROUP_NAMES:?}: unknown {unknown:?}, \
                 missing {missing:?}"
            )));
        }
        Ok(Self {
            config: TrainConfig {
                adam: AdamConfig {
                    learning_rates: GROUP_NAMES.map(|name| learning_rates[name]),
                    beta1: betas.0,
                    beta2: betas.1,
                    eps,
                },
                losses: LossWeights {
                    l1: lambda_l1,
                    ssim: lambda_ssim,
                    temporal: lambda_temporal,
                    geo: lambda_geo,
                },
                settings: render_settings(background, antialiased),
            },
        })
    }

    #[getter]
    fn learning_rates(&self) -> BTreeMap<&'static str, f64> {
        GROUP_NAMES
            .into_iter()
            .zip(self.config.adam.learning_rates)
            .collect()
    }

    #[getter]
    fn betas(&self) -> (f64, f64) {
        (self.config.adam.beta1, self.config.adam.beta2)
    }

    #[getter]
    fn eps(&self) -> f64 {
        self.config.adam.eps
    }

    #[getter]
    fn lambda_l1(&self) -> f32 {
        self.config.losses.l1
    }

    #[getter]
    fn lambda_ssim(&self) -> f32 {
        self.config.losses.ssim
    }

    #[getter]
    fn lambda_temporal(&self) -> f32 {
        self.config.losses.temporal
    }

    #[getter]
    fn lambda_geo(&self) -> f32 {
        self.config.losses.geo
    }

    #[getter]
    fn background(&self) -> [f32; 3] {
        self.config.settings.background
    }

    #[getter]
    fn antialiased(&self) -> bool {
        self.config.settings.antialiased
    }

    fn __repr__(&self) -> String {
        let c = &self.config;
        format!(
            "TrainSettings(learning_rates={:?}, betas=({}, {}), eps={}, lambda_l1={}, \
             lambda_ssim={}, lambda_temporal={}, lambda_geo={}, background={:?}, \
             antialiased={})",
            self.learning_rates(),
            c.adam.beta1,
            c.adam.beta2,
            c.adam.eps,
            c.losses.l1,
            c.losses.ssim,
            c.losses.temporal,
            c.losses.geo,
            c.settings.background,
            if c.settings.antialiased {
                "True"
            } else {
                "False"
            }
        )
    }
}

fn optional<'a>(
    name: &str,
    array: &'a Option<PyReadonlyArray1<'_, f32>>,
) -> PyResult<Option<&'a [f32]>> {
    array.as_ref().map(|a| slice(name, a)).transpose()
}

/// An array's values in row-major order, whatever its shape and memory layout.
fn flattened(array: &PyReadonlyArrayDyn<'_, f32>) -> Vec<f32> {
    array.as_array().iter().copied().collect()
}

/// One view's targets (train::ViewTargets): the camera, the target rgb (H·W·3 values),
/// the loss weight (H·W), Θ's z-depth (H·W, for L_geo) and the previous timestamp's render
/// (H·W·3, for L_temporal) where the loss has them, the whole view's weight sum and the
/// loss sums over the rest of it when the view is a window of a larger one, and the time
/// it shows in frames (a spacetime set is drawn at it). Arrays are float32 of any shape
/// with those counts (read in row-major order) and copied.
#[pyclass(name = "ViewTarget", module = "pano4d._core", frozen)]
pub struct PyViewTarget {
    camera: crate::camera::Camera,
    time: f64,
    rgb: Vec<f32>,
    weight: Vec<f32>,
    depth: Option<Vec<f32>>,
    previous: Option<Vec<f32>>,
    weight_sum: f32,
    outside_sums: [f32; OUTSIDE_SUMS],
}

#[pymethods]
impl PyViewTarget {
    #[new]
    #[pyo3(signature = (*, view, rgb, weight, weight_sum, outside_sums, depth=None, previous=None, time=0.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        view: PyRef<'_, PyView>,
        rgb: PyReadonlyArrayDyn<'_, f32>,
        weight: PyReadonlyArrayDyn<'_, f32>,
        weight_sum: f32,
        outside_sums: [f32; OUTSIDE_SUMS],
        depth: Option<PyReadonlyArrayDyn<'_, f32>>,
        previous: Option<PyReadonlyArrayDyn<'_, f32>>,
        time: f64,
    ) -> Self {
        Self {
            camera: view.camera,
            time,
            rgb: flattened(&rgb),
            weight: flattened(&weight),
            depth: depth.as_ref().map(flattened),
            previous: previous.as_ref().map(flattened),
            weight_sum,
            outside_sums,
        }
    }
}

impl PyViewTarget {
    fn targets(&self) -> ViewTargets<'_> {
        ViewTargets {
            camera: self.camera,
            time: self.time,
            rgb: &self.rgb,
            weight: &self.weight,
            depth: self.depth.as_deref(),
            previous: self.previous.as_deref(),
            weight_sum: self.weight_sum,
            outside: self.outside_sums,
        }
    }
}

/// One step's loss and its parts (train::LossParts), by name.
#[pyclass(name = "LossParts", module = "pano4d._core", frozen)]
pub struct PyLossParts {
    parts: LossParts,
}

#[pymethods]
impl PyLossParts {
    /// L, the weighted sum of the terms below (L_sem, on the host, not included).
    #[getter]
    fn total(&self) -> f32 {
        self.parts.total
    }

    #[getter]
    fn l1(&self) -> f32 {
        self.parts.l1
    }

    /// 1 − SSIM.
    #[getter]
    fn d_ssim(&self) -> f32 {
        self.parts.d_ssim
    }

    /// L_temporal; 0 for a view without a previous render.
    #[getter]
    fn temporal(&self) -> f32 {
        self.parts.temporal
    }

    /// L_geo before its weight (1 − Pearson); 0 where it did not apply.
    #[getter]
    fn one_minus_pearson(&self) -> f32 {
        self.parts.one_minus_pearson
    }

    /// Σ weight over the pixels the render covers (alpha > 0.5).
    #[getter]
    fn covered_weight(&self) -> f32 {
        self.parts.covered_weight
    }

    /// Whether L_geo applied this step.
    #[getter]
    fn geo_applied(&self) -> bool {
        self.parts.geo_applied
    }

    fn __repr__(&self) -> String {
        let p = &self.parts;
        format!(
            "LossParts(total={}, l1={}, d_ssim={}, temporal={}, one_minus_pearson={}, \
             covered_weight={}, geo_applied={})",
            p.total,
            p.l1,
            p.d_ssim,
            p.temporal,
            p.one_minus_pearson,
            p.covered_weight,
            if p.geo_applied { "True" } else { "False" }
        )
    }
}

/// The losses of given pixels (`TrainSession.loss_gradient`): their gradient and the parts.
#[pyclass(name = "LossGradient", module = "pano4d._core", frozen)]
pub struct PyLossGradient {
    pixel_gradient: Py<PyArray1<f32>>,
    parts: Py<PyLossParts>,
}

#[pymethods]
impl PyLossGradient {
    /// d L / d pixels, H·W·5 float32 (the forward's layout).
    #[getter]
    fn pixel_gradient(&self, py: Python<'_>) -> Py<PyArray1<f32>> {
        self.pixel_gradient.clone_ref(py)
    }

    #[getter]
    fn parts(&self, py: Python<'_>) -> Py<PyLossParts> {
        self.parts.clone_ref(py)
    }
}

/// The renderer's check of the frames since the last one (raster::IntersectionCheck).
#[pyclass(name = "FrameCheck", module = "pano4d._core", frozen)]
pub struct PyFrameCheck {
    check: IntersectionCheck,
}

#[pymethods]
impl PyFrameCheck {
    /// Frames that outgrew their intersection buffers (drew only the background).
    #[getter]
    fn overflowed(&self) -> u32 {
        self.check.overflowed
    }

    /// The most intersections of any frame so far.
    #[getter]
    fn max_intersections(&self) -> u32 {
        self.check.max_intersections
    }

    /// The intersections a frame has room for from now on.
    #[getter]
    fn capacity(&self) -> u32 {
        self.check.capacity
    }
}

/// Bytes the session has moved between host and device (train::Traffic).
#[pyclass(name = "Traffic", module = "pano4d._core", frozen)]
pub struct PyTraffic {
    traffic: Traffic,
}

#[pymethods]
impl PyTraffic {
    #[getter]
    fn uploaded(&self) -> u64 {
        self.traffic.uploaded
    }

    #[getter]
    fn read_back(&self) -> u64 {
        self.traffic.read_back
    }
}

/// The trained set and its optimiser state, read back (train::TrainState): the parameters
/// and Adam's moments as `GaussianArrays` or `SpacetimeArrays`, the kind the session
/// trains (the moments of the means and position terms are their offsets'), the
/// per-Gaussian offset unit and gradient statistics, and the Adam step count.
#[pyclass(name = "TrainState", module = "pano4d._core", frozen)]
pub struct PyTrainState {
    params: Py<PyAny>,
    exp_avg: Py<PyAny>,
    exp_avg_sq: Py<PyAny>,
    unit: Py<PyArray1<f32>>,
    grad_accum: Py<PyArray1<f32>>,
    grad_count: Py<PyArray1<f32>>,
    adam_steps: u64,
}

#[pymethods]
impl PyTrainState {
    #[getter]
    fn params(&self, py: Python<'_>) -> Py<PyAny> {
        self.params.clone_ref(py)
    }

    #[getter]
    fn exp_avg(&self, py: Python<'_>) -> Py<PyAny> {
        self.exp_avg.clone_ref(py)
    }

    #[getter]
    fn exp_avg_sq(&self, py: Python<'_>) -> Py<PyAny> {
        self.exp_avg_sq.clone_ref(py)
    }

    /// (N,) each Gaussian's offset unit.
    #[getter]
    fn unit(&self, py: Python<'_>) -> Py<PyArray1<f32>> {
        self.unit.clone_ref(py)
    }

    /// (N,) Σ ‖g_offset‖ across the ray since the last densification.
    #[getter]
    fn grad_accum(&self, py: Python<'_>) -> Py<PyArray1<f32>> {
        self.grad_accum.clone_ref(py)
    }

    /// (N,) the steps where that gradient was non-zero.
    #[getter]
    fn grad_count(&self, py: Python<'_>) -> Py<PyArray1<f32>> {
        self.grad_count.clone_ref(py)
    }

    #[getter]
    fn adam_steps(&self) -> u64 {
        self.adam_steps
    }
}

/// A trained set as it crosses into the session, or Adam moments of one: a set of
/// Gaussians or a spacetime set.
#[derive(FromPyObject)]
enum TrainedArrays<'py> {
    Gaussians(PyRef<'py, PyGaussianArrays>),
    Spacetime(PyRef<'py, PySpacetimeArrays>),
}

impl TrainedArrays<'_> {
    /// The Gaussians and a spacetime set's time parameters, borrowed.
    fn input(&self) -> (SceneInput<'_>, Option<TimeInput<'_>>) {
        match self {
            Self::Gaussians(g) => (g.input(), None),
            Self::Spacetime(s) => {
                let (canonical, time) = s.input();
                (canonical, Some(time))
            }
        }
    }

    /// The values in the session's layout (train::TrainState's).
    fn packed(&self) -> Vec<f32> {
        let (gaussians, time) = self.input();
        packed_parameters(&gaussians, time)
    }
}

/// The trained Gaussians, their Adam moments and the stage's targets on the GPU, after a
/// frozen static set.
#[pyclass(name = "TrainSession", module = "pano4d._core")]
pub struct PyTrainSession {
    inner: TrainSession,
}

impl PyTrainSession {
    /// `n` Gaussians of the session's packed read-back of the scene as `GaussianArrays`.
    fn scene_arrays(&self, packed: &[f32], n: usize) -> PyGaussianArrays {
        PyGaussianArrays::from_packed(packed, n, self.inner.sh_degree())
    }

    /// The `n` trained Gaussians of a read-back in the session's layout (parameters,
    /// moments, gradients) as the kind the session trains: `GaussianArrays` or
    /// `SpacetimeArrays`.
    fn trained_arrays(&self, py: Python<'_>, packed: &[f32], n: usize) -> PyResult<Py<PyAny>> {
        let degree = self.inner.sh_degree();
        Ok(match self.inner.time_model() {
            None => Py::new(py, self.scene_arrays(packed, n))?.into_any(),
            Some(model) => {
                let set = SpacetimeSet::from_packed(packed, n, degree, model);
                Py::new(py, PySpacetimeArrays::from(set))?.into_any()
            }
        })
    }
}

#[pymethods]
impl PyTrainSession {
    /// `static_set`: the frozen static set drawn before the trained one (may be empty; the
    /// trained set's SH degree); `trained`: the set to train, `GaussianArrays` or
    /// `SpacetimeArrays` (drawn at each step's view time); `unit`: each trained Gaussian's
    /// offset unit; `views`: the ViewTargets steps draw from (a view may be a window of a
    /// larger one: train::ViewTargets); `settings`: a TrainSettings.
    #[new]
    #[pyo3(signature = (*, static_set, trained, unit, views, settings))]
    fn new(
        py: Python<'_>,
        static_set: PyRef<'_, PyGaussianArrays>,
        trained: TrainedArrays<'_>,
        unit: PyReadonlyArray1<'_, f32>,
        views: Vec<PyRef<'_, PyViewTarget>>,
        settings: PyRef<'_, PyTrainSettings>,
    ) -> PyResult<Self> {
        let unit = slice("unit", &unit)?;
        let targets: Vec<ViewTargets<'_>> = views.iter().map(|v| v.targets()).collect();
        let config = settings.config;
        let static_set = static_set.input();
        let (gaussians, time) = trained.input();
        let trained = TrainedInput {
            gaussians,
            time,
            unit,
            exp_avg: None,
            exp_avg_sq: None,
            grad_accum: None,
            grad_count: None,
            adam_steps: 0,
        };
        let inner = py
            .detach(|| {
                with_renderer(|r| TrainSession::new(r, static_set, trained, &targets, config))
            })
            .map_err(to_py)?;
        Ok(Self { inner })
    }

    /// The settings the session runs with, as the device has them (f32 weights).
    #[getter]
    fn settings(&self) -> PyTrainSettings {
        PyTrainSettings {
            config: self.inner.config(),
        }
    }

    /// One step (forward, losses, backward, Adam) on view `view`; waits for nothing.
    fn step(&mut self, py: Python<'_>, view: usize) -> PyResult<()> {
        let s = &mut self.inner;
        py.detach(|| with_renderer(|r| s.step(r, view)))
            .map_err(to_py)
    }

    /// Forward, losses and backward of view `view`, without the Adam step.
    fn forward_backward(&mut self, py: Python<'_>, view: usize) -> PyResult<()> {
        let s = &mut self.inner;
        py.detach(|| with_renderer(|r| s.forward_backward(r, view)))
            .map_err(to_py)
    }

    /// The last forward's pixels, H·W·5 float32.
    fn read_render<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let s = &mut self.inner;
        let pixels = py
            .detach(|| with_renderer(|r| s.read_render(r)))
            .map_err(to_py)?;
        Ok(PyArray1::from_vec(py, pixels))
    }

    /// Renders at another view (of at most the largest view's pixels); returns its pixels
    /// (H·W·5).
    fn render_at<'py>(
        &mut self,
        py: Python<'py>,
        view: PyRef<'py, PyView>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let s = &mut self.inner;
        let camera = view.camera;
        let pixels = py
            .detach(|| with_renderer(|r| s.render_at(r, &camera)))
            .map_err(to_py)?;
        Ok(PyArray1::from_vec(py, pixels))
    }

    /// The losses of view `view` on given pixels (H·W·5) instead of a render, for checking
    /// the loss kernels.
    fn loss_gradient(
        &mut self,
        py: Python<'_>,
        view: usize,
        pixels: PyReadonlyArray1<'_, f32>,
    ) -> PyResult<PyLossGradient> {
        let p = slice("pixels", &pixels)?;
        let s = &mut self.inner;
        let (gradient, parts) = py.detach(|| s.loss_gradient(view, p)).map_err(to_py)?;
        Ok(PyLossGradient {
            pixel_gradient: PyArray1::from_vec(py, gradient).unbind(),
            parts: Py::new(py, PyLossParts { parts })?,
        })
    }

    /// Adds the gradient of a loss on render_at's pixels (H·W·5) to this step's.
    fn backward_at(&mut self, py: Python<'_>, v_pixels: PyReadonlyArray1<'_, f32>) -> PyResult<()> {
        let v = slice("v_pixels", &v_pixels)?;
        let s = &mut self.inner;
        py.detach(|| with_renderer(|r| s.backward_at(r, v)))
            .map_err(to_py)
    }

    /// The Adam step that completes forward_backward.
    fn apply_adam(&mut self, py: Python<'_>) -> PyResult<()> {
        let s = &mut self.inner;
        py.detach(|| s.apply_adam()).map_err(to_py)
    }

    /// Adam on given gradients of the whole scene (the static set, then the trained set:
    /// what the backward writes).
    fn apply_gradients(
        &mut self,
        py: Python<'_>,
        grads: PyRef<'_, PyGaussianArrays>,
    ) -> PyResult<()> {
        let packed = grads.input().packed();
        let s = &mut self.inner;
        py.detach(|| s.apply_gradients(&packed)).map_err(to_py)
    }

    /// Sizes the renderer's intersection buffers for every view of the current scene (one
    /// wait): at the start of a stage and after set_trained.
    fn reserve_frames(&mut self, py: Python<'_>) -> PyResult<()> {
        let s = &mut self.inner;
        py.detach(|| with_renderer(|r| s.reserve_frames(r)))
            .map_err(to_py)
    }

    /// The frames since the last check; grows the room when the largest frame came near
    /// it. A 16-byte read-back: call it with the loss.
    fn check_frames(&mut self, py: Python<'_>) -> PyResult<PyFrameCheck> {
        let s = &mut self.inner;
        let check = py
            .detach(|| with_renderer(|r| s.check_frames(r)))
            .map_err(to_py)?;
        Ok(PyFrameCheck { check })
    }

    /// The last step's loss and its parts.
    fn loss(&mut self, py: Python<'_>) -> PyResult<PyLossParts> {
        let s = &mut self.inner;
        let parts = py.detach(|| s.loss()).map_err(to_py)?;
        Ok(PyLossParts { parts })
    }

    /// The trained set and its optimiser state (one round trip).
    fn state(&mut self, py: Python<'_>) -> PyResult<PyTrainState> {
        let s = &mut self.inner;
        let state = py.detach(|| s.state()).map_err(to_py)?;
        let n = state.unit.len();
        let arrays = |packed: &[f32]| self.trained_arrays(py, packed, n);
        Ok(PyTrainState {
            params: arrays(&state.params)?,
            exp_avg: arrays(&state.exp_avg)?,
            exp_avg_sq: arrays(&state.exp_avg_sq)?,
            unit: PyArray1::from_vec(py, state.unit).unbind(),
            grad_accum: PyArray1::from_vec(py, state.grad_accum).unbind(),
            grad_count: PyArray1::from_vec(py, state.grad_count).unbind(),
            adam_steps: state.adam_steps,
        })
    }

    /// The trained set's parameters, of the kind it was given.
    fn params(&mut self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let s = &mut self.inner;
        let packed = py.detach(|| s.params()).map_err(to_py)?;
        self.trained_arrays(py, &packed, self.inner.len())
    }

    /// The trained parameters' gradient, of the kind the session trains (the means' and
    /// position terms' themselves, not their offsets'): of the last backward
    /// (forward_backward, with backward_at's), or of `scene_gradient` (the static set, then
    /// the trained set's snapshot: what the backward writes), which replaces it; a
    /// spacetime set's through the adjoint of its evaluation at the last view's time.
    #[pyo3(signature = (scene_gradient=None))]
    fn parameter_gradient(
        &mut self,
        py: Python<'_>,
        scene_gradient: Option<PyRef<'_, PyGaussianArrays>>,
    ) -> PyResult<Py<PyAny>> {
        let given = scene_gradient.map(|g| g.input().packed());
        let s = &mut self.inner;
        let packed = py
            .detach(|| s.parameter_gradient(given.as_deref()))
            .map_err(to_py)?;
        self.trained_arrays(py, &packed, self.inner.len())
    }

    /// The whole scene: the static set, then the trained set (a spacetime set's canonical
    /// Gaussians).
    fn scene(&mut self, py: Python<'_>) -> PyResult<PyGaussianArrays> {
        let s = &mut self.inner;
        let packed = py.detach(|| s.scene()).map_err(to_py)?;
        let n = self.inner.static_len() + self.inner.len();
        Ok(self.scene_arrays(&packed, n))
    }

    /// Replaces the trained set and its optimiser state (densification, resume) with a set
    /// of the session's kind; moments and statistics left out start at zero.
    #[pyo3(signature = (*, trained, unit, exp_avg=None, exp_avg_sq=None, grad_accum=None, grad_count=None, adam_steps=0))]
    #[allow(clippy::too_many_arguments)]
    fn set_trained(
        &mut self,
        py: Python<'_>,
        trained: TrainedArrays<'_>,
        unit: PyReadonlyArray1<'_, f32>,
        exp_avg: Option<TrainedArrays<'_>>,
        exp_avg_sq: Option<TrainedArrays<'_>>,
        grad_accum: Option<PyReadonlyArray1<'_, f32>>,
        grad_count: Option<PyReadonlyArray1<'_, f32>>,
        adam_steps: u64,
    ) -> PyResult<()> {
        let unit = slice("unit", &unit)?;
        let exp_avg = exp_avg.map(|m| m.packed());
        let exp_avg_sq = exp_avg_sq.map(|m| m.packed());
        let (gaussians, time) = trained.input();
        let input = TrainedInput {
            gaussians,
            time,
            unit,
            exp_avg: exp_avg.as_deref(),
            exp_avg_sq: exp_avg_sq.as_deref(),
            grad_accum: optional("grad_accum", &grad_accum)?,
            grad_count: optional("grad_count", &grad_count)?,
            adam_steps,
        };
        let s = &mut self.inner;
        py.detach(|| s.set_trained(input)).map_err(to_py)
    }

    /// Bytes moved between host and device by the session so far.
    fn traffic(&self) -> PyTraffic {
        PyTraffic {
            traffic: self.inner.traffic(),
        }
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTrainSettings>()?;
    m.add_class::<PyViewTarget>()?;
    m.add_class::<PyLossParts>()?;
    m.add_class::<PyLossGradient>()?;
    m.add_class::<PyFrameCheck>()?;
    m.add_class::<PyTraffic>()?;
    m.add_class::<PyTrainState>()?;
    m.add_class::<PyTrainSession>()?;
    Ok(())
}
