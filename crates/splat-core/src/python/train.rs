//! Python binding of the resident training loop: `TrainSession` (driven by
//! `pano4d.lift.resident.ResidentTrainer`).
//!
//! Gaussian sets cross as one packed float32 array each, in the shaders' SoA order (means,
//! log-scales, quaternions, opacity logits, SH), with their count; so do the Adam moments.
//! The session's knobs cross as one `TrainSettings` (the Rust [`TrainConfig`]), built by
//! keyword. Every call runs on the process-wide renderer (python/raster.rs) with the GIL
//! released.

use std::collections::BTreeMap;

use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::raster::{camera_from, slice, to_py, with_renderer};
use crate::gaussians::{SceneInput, BASE_FLOATS};
use crate::raster::RenderSettings;
use crate::train::{
    AdamConfig, LossWeights, TrainConfig, TrainSession, TrainedInput, ViewTargets, GROUPS,
    OUTSIDE_SUMS,
};

/// The learning-rate groups by name, in [`crate::train::AdamConfig::learning_rates`]' order
/// (GaussianTrainer's parameter groups: means trained as offsets in units of each
/// Gaussian's initial depth).
const GROUP_NAMES: [&str; GROUPS] = [
    "offsets",
    "log_scales",
    "quats",
    "opacity_logits",
    "sh_dc",
    "sh_rest",
];

/// What a training session is configured with: Adam's learning rates (by group name), β
/// and ε, the weights of the device's losses and the background. Built by keyword only, read
/// back by name (`TrainSession.settings` returns the session's own).
#[pyclass(name = "TrainSettings", module = "pano4d._core", frozen)]
#[derive(Clone)]
pub struct PyTrainSettings {
    config: TrainConfig,
}

#[pymethods]
impl PyTrainSettings {
    /// `learning_rates`: {group: rate} for exactly the groups offsets, log_scales, quats,
    /// opacity_logits, sh_dc, sh_rest; `lambda_l1`, `lambda_ssim`, `lambda_temporal`,
    /// `lambda_geo`: the weights of L1, D-SSIM, L_temporal and L_geo.
    #[new]
    #[pyo3(signature = (*, learning_rates, betas, eps, lambda_l1, lambda_ssim, lambda_temporal, lambda_geo, background))]
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
                settings: RenderSettings {
                    background,
                    ..Default::default()
                },
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

    fn __repr__(&self) -> String {
        let c = &self.config;
        format!(
            "TrainSettings(learning_rates={:?}, betas=({}, {}), eps={}, lambda_l1={}, \
             lambda_ssim={}, lambda_temporal={}, lambda_geo={}, background={:?})",
            self.learning_rates(),
            c.adam.beta1,
            c.adam.beta2,
            c.adam.eps,
            c.losses.l1,
            c.losses.ssim,
            c.losses.temporal,
            c.losses.geo,
            c.settings.background
        )
    }
}

/// A packed SoA array of `n` Gaussians as a [`SceneInput`].
fn unpack<'a>(name: &str, packed: &'a [f32], n: usize) -> PyResult<SceneInput<'a>> {
    let bad = || {
        PyValueError::new_err(format!(
            "{name} has {} values: not n·(11 + 3k) for n = {n} and k in {{1, 4, 9, 16}}",
            packed.len()
        ))
    };
    let k = if n == 0 {
        1
    } else {
        if packed.len() % n != 0 {
            return Err(bad());
        }
        let per = packed.len() / n;
        if per < BASE_FLOATS || (per - BASE_FLOATS) % 3 != 0 {
            return Err(bad());
        }
        (per - BASE_FLOATS) / 3
    };
    if ![1, 4, 9, 16].contains(&k) {
        return Err(bad());
    }
    let mut parts = [3 * n, 3 * n, 4 * n, n, 3 * k * n]
        .into_iter()
        .scan(0, |start, len| {
            let part = &packed[*start..*start + len];
            *start += len;
            Some(part)
        });
    let mut next = || parts.next().unwrap_or(&[]);
    Ok(SceneInput {
        means: next(),
        log_scales: next(),
        quats: next(),
        opacity_logits: next(),
        sh: next(),
    })
}

fn optional<'a>(
    name: &str,
    array: &'a Option<PyReadonlyArray1<'_, f32>>,
) -> PyResult<Option<&'a [f32]>> {
    array.as_ref().map(|a| slice(name, a)).transpose()
}

/// (K, world_to_cam, half_fov_tan, width, height, rgb, weight, depth, previous, weight_sum,
/// outside) of one view.
type PyView<'py> = (
    PyReadonlyArray2<'py, f64>,
    PyReadonlyArray2<'py, f64>,
    [f64; 2],
    u32,
    u32,
    PyReadonlyArray1<'py, f32>,
    PyReadonlyArray1<'py, f32>,
    Option<PyReadonlyArray1<'py, f32>>,
    Option<PyReadonlyArray1<'py, f32>>,
    f32,
    [f32; OUTSIDE_SUMS],
);

/// The trained Gaussians, their Adam moments and the stage's targets on the GPU.
#[pyclass(name = "TrainSession", module = "pano4d._core")]
pub struct PyTrainSession {
    inner: TrainSession,
}

#[pymethods]
impl PyTrainSession {
    /// `context`/`trained`: packed Gaussians (see the module docs); `unit`: each trained
    /// Gaussian's offset unit; `views`: (K, world_to_cam, half_fov_tan, width, height, rgb,
    /// weight, depth or None, previous or None, weight_sum, outside sums) tuples (a view may
    /// be a window of a larger one: train::ViewTargets); `settings`: a TrainSettings.
    #[new]
    fn new(
        py: Python<'_>,
        context: PyReadonlyArray1<'_, f32>,
        context_len: usize,
        trained: PyReadonlyArray1<'_, f32>,
        unit: PyReadonlyArray1<'_, f32>,
        views: Vec<PyView<'_>>,
        settings: PyRef<'_, PyTrainSettings>,
    ) -> PyResult<Self> {
        let unit = slice("unit", &unit)?;
        let context = unpack("context", slice("context", &context)?, context_len)?;
        let gaussians = unpack("trained", slice("trained", &trained)?, unit.len())?;
        let mut targets = Vec::with_capacity(views.len());
        for (k, w2c, tan, width, height, rgb, weight, depth, previous, weight_sum, outside) in
            &views
        {
            targets.push(ViewTargets {
                camera: camera_from(k, w2c, *tan, *width, *height)?,
                rgb: slice("rgb", rgb)?,
                weight: slice("weight", weight)?,
                depth: optional("depth", depth)?,
                previous: optional("previous", previous)?,
                weight_sum: *weight_sum,
                outside: *outside,
            });
        }
        let config = settings.config;
        let trained = TrainedInput {
            gaussians,
            unit,
            exp_avg: None,
            exp_avg_sq: None,
            grad_accum: None,
            grad_count: None,
            adam_steps: 0,
        };
        let inner = py
            .detach(|| with_renderer(|r| TrainSession::new(r, context, trained, &targets, config)))
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

    /// Renders at another camera (of at most the largest view's pixels); returns its
    /// pixels (H·W·5).
    fn render_at<'py>(
        &mut self,
        py: Python<'py>,
        k: PyReadonlyArray2<'py, f64>,
        world_to_cam: PyReadonlyArray2<'py, f64>,
        half_fov_tan: [f64; 2],
        width: u32,
        height: u32,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let s = &mut self.inner;
        let camera = camera_from(&k, &world_to_cam, half_fov_tan, width, height)?;
        let pixels = py
            .detach(|| with_renderer(|r| s.render_at(r, &camera)))
            .map_err(to_py)?;
        Ok(PyArray1::from_vec(py, pixels))
    }

    /// The losses of view `view` on given pixels (H·W·5) instead of a render: (pixel
    /// gradient, loss parts). For checking the loss kernels.
    fn loss_gradient<'py>(
        &mut self,
        py: Python<'py>,
        view: usize,
        pixels: PyReadonlyArray1<'py, f32>,
    ) -> PyResult<(Bound<'py, PyArray1<f32>>, Vec<f32>)> {
        let p = slice("pixels", &pixels)?;
        let s = &mut self.inner;
        let (gradient, loss) = py.detach(|| s.loss_gradient(view, p)).map_err(to_py)?;
        Ok((PyArray1::from_vec(py, gradient), loss.to_vec()))
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

    /// Adam on given gradients (context + trained, the backward's packed layout).
    fn apply_gradients(
        &mut self,
        py: Python<'_>,
        grads: PyReadonlyArray1<'_, f32>,
    ) -> PyResult<()> {
        let g = slice("grads", &grads)?;
        let s = &mut self.inner;
        py.detach(|| s.apply_gradients(g)).map_err(to_py)
    }

    /// Sizes the renderer's intersection buffers for every view of the current scene (one
    /// wait): at the start of a stage and after set_trained.
    fn reserve_frames(&mut self, py: Python<'_>) -> PyResult<()> {
        let s = &mut self.inner;
        py.detach(|| with_renderer(|r| s.reserve_frames(r)))
            .map_err(to_py)
    }

    /// (frames that overflowed their intersection buffers since the last check, the
    /// largest frame's intersections, the room from now on); grows the room when the
    /// largest frame came near it. A 16-byte read-back: call it with the loss.
    fn check_frames(&mut self, py: Python<'_>) -> PyResult<(u32, u32, u32)> {
        let s = &mut self.inner;
        let c = py
            .detach(|| with_renderer(|r| s.check_frames(r)))
            .map_err(to_py)?;
        Ok((c.overflowed, c.max_intersections, c.capacity))
    }

    /// The last step's loss parts: (L, L1, 1 − SSIM, L_temporal, 1 − Pearson, covered
    /// weight, 1.0 if L_geo applied else 0.0).
    fn loss(&mut self, py: Python<'_>) -> PyResult<Vec<f32>> {
        let s = &mut self.inner;
        Ok(py.detach(|| s.loss()).map_err(to_py)?.to_vec())
    }

    /// The trained set and optimiser state: {params, unit, exp_avg, exp_avg_sq,
    /// grad_accum, grad_count} as flat float32 arrays (params and moments packed) and
    /// adam_steps.
    fn state<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &mut self.inner;
        let state = py.detach(|| s.state()).map_err(to_py)?;
        let out = PyDict::new(py);
        out.set_item("params", PyArray1::from_vec(py, state.params))?;
        out.set_item("unit", PyArray1::from_vec(py, state.unit))?;
        out.set_item("exp_avg", PyArray1::from_vec(py, state.exp_avg))?;
        out.set_item("exp_avg_sq", PyArray1::from_vec(py, state.exp_avg_sq))?;
        out.set_item("grad_accum", PyArray1::from_vec(py, state.grad_accum))?;
        out.set_item("grad_count", PyArray1::from_vec(py, state.grad_count))?;
        out.set_item("adam_steps", state.adam_steps)?;
        Ok(out)
    }

    /// The trained set's parameters as one packed float32 array.
    fn params<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let s = &mut self.inner;
        let packed = py.detach(|| s.params()).map_err(to_py)?;
        Ok(PyArray1::from_vec(py, packed))
    }

    /// The whole scene (context, then trained set) as one packed float32 array.
    fn scene<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let s = &mut self.inner;
        let packed = py.detach(|| s.scene()).map_err(to_py)?;
        Ok(PyArray1::from_vec(py, packed))
    }

    /// Replaces the trained set and its optimiser state (densification, resume); moments
    /// and statistics left out start at zero.
    #[pyo3(signature = (trained, unit, exp_avg=None, exp_avg_sq=None, grad_accum=None, grad_count=None, adam_steps=0))]
    #[allow(clippy::too_many_arguments)]
    fn set_trained(
        &mut self,
        py: Python<'_>,
        trained: PyReadonlyArray1<'_, f32>,
        unit: PyReadonlyArray1<'_, f32>,
        exp_avg: Option<PyReadonlyArray1<'_, f32>>,
        exp_avg_sq: Option<PyReadonlyArray1<'_, f32>>,
        grad_accum: Option<PyReadonlyArray1<'_, f32>>,
        grad_count: Option<PyReadonlyArray1<'_, f32>>,
        adam_steps: u64,
    ) -> PyResult<()> {
        let unit = slice("unit", &unit)?;
        let input = TrainedInput {
            gaussians: unpack("trained", slice("trained", &trained)?, unit.len())?,
            unit,
            exp_avg: optional("exp_avg", &exp_avg)?,
            exp_avg_sq: optional("exp_avg_sq", &exp_avg_sq)?,
            grad_accum: optional("grad_accum", &grad_accum)?,
            grad_count: optional("grad_count", &grad_count)?,
            adam_steps,
        };
        let s = &mut self.inner;
        py.detach(|| s.set_trained(input)).map_err(to_py)
    }

    /// (bytes uploaded, bytes read back) by the session so far.
    fn traffic(&self) -> (u64, u64) {
        let t = self.inner.traffic();
        (t.uploaded, t.read_back)
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTrainSettings>()?;
    m.add_class::<PyTrainSession>()?;
    Ok(())
}
