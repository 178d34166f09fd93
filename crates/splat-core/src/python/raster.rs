//! Python bindings of the rasteriser: `render_forward`, `render_backward`, `footprints`,
//! `adapter_info`.
//!
//! One process-wide [`Renderer`] (device, pipelines, buffers) is created on first use
//! and reused; calls are serialised by a mutex and run with the GIL released.

use std::sync::{Mutex, OnceLock};

use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::camera::Camera;
use crate::gaussians::SceneInput;
use crate::raster::{GpuContext, RasterError, RenderSettings, Renderer};

static RENDERER: OnceLock<Mutex<Option<Renderer>>> = OnceLock::new();

pub(super) fn to_py(e: RasterError) -> PyErr {
    match e {
        RasterError::InvalidInput(_) => PyValueError::new_err(e.to_string()),
        _ => PyRuntimeError::new_err(e.to_string()),
    }
}

/// Runs `f` on the shared renderer, creating it on first use.
pub(super) fn with_renderer<T>(
    f: impl FnOnce(&mut Renderer) -> Result<T, RasterError>,
) -> Result<T, RasterError> {
    let cell = RENDERER.get_or_init(|| Mutex::new(None));
    // A panic in another call cannot leave the renderer half-updated in a way that
    // matters: every call rewrites the buffers it reads.
    let mut guard = cell.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if guard.is_none() {
        *guard = Some(Renderer::new(GpuContext::new()?)?);
    }
    f(guard.as_mut().expect("created above"))
}

pub(super) fn camera_from(
    k: &PyReadonlyArray2<'_, f64>,
    w2c: &PyReadonlyArray2<'_, f64>,
    half_fov_tan: [f64; 2],
    width: u32,
    height: u32,
) -> PyResult<Camera> {
    let k = k.as_array();
    let w2c = w2c.as_array();
    if k.shape() != [3, 3] || w2c.shape()[1] != 4 || !(3..=4).contains(&w2c.shape()[0]) {
        return Err(PyValueError::new_err(
            "K must be 3x3 and world_to_cam 3x4 or 4x4",
        ));
    }
    let kk = std::array::from_fn(|r| std::array::from_fn(|c| k[[r, c]]));
    let ww = std::array::from_fn(|r| std::array::from_fn(|c| w2c[[r, c]]));
    Ok(Camera {
        half_fov_tan: half_fov_tan.into(),
        ..Camera::from_matrices(kk, ww, width, height)
    })
}

pub(super) fn slice<'a>(name: &str, a: &'a PyReadonlyArray1<'_, f32>) -> PyResult<&'a [f32]> {
    a.as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name} must be a C-contiguous float32 array")))
}

/// Borrows the five flat float32 arrays as a [`SceneInput`].
fn scene<'a>(
    means: &'a PyReadonlyArray1<'_, f32>,
    log_scales: &'a PyReadonlyArray1<'_, f32>,
    quats: &'a PyReadonlyArray1<'_, f32>,
    opacity_logits: &'a PyReadonlyArray1<'_, f32>,
    sh: &'a PyReadonlyArray1<'_, f32>,
) -> PyResult<SceneInput<'a>> {
    Ok(SceneInput {
        means: slice("means", means)?,
        log_scales: slice("log_scales", log_scales)?,
        quats: slice("quats", quats)?,
        opacity_logits: slice("opacity_logits", opacity_logits)?,
        sh: slice("sh", sh)?,
    })
}

/// Renders; returns (H*W*5 float32: r, g, b, alpha, sum z*alpha*T; intersection count).
#[pyfunction]
#[pyo3(signature = (means, log_scales, quats, opacity_logits, sh, k, world_to_cam, half_fov_tan, width, height, background, antialiased))]
#[allow(clippy::too_many_arguments)]
fn render_forward<'py>(
    py: Python<'py>,
    means: PyReadonlyArray1<'py, f32>,
    log_scales: PyReadonlyArray1<'py, f32>,
    quats: PyReadonlyArray1<'py, f32>,
    opacity_logits: PyReadonlyArray1<'py, f32>,
    sh: PyReadonlyArray1<'py, f32>,
    k: PyReadonlyArray2<'py, f64>,
    world_to_cam: PyReadonlyArray2<'py, f64>,
    half_fov_tan: [f64; 2],
    width: u32,
    height: u32,
    background: [f32; 3],
    antialiased: bool,
) -> PyResult<(Bound<'py, PyArray1<f32>>, u32)> {
    let camera = camera_from(&k, &world_to_cam, half_fov_tan, width, height)?;
    let input = scene(&means, &log_scales, &quats, &opacity_logits, &sh)?;
    let settings = RenderSettings {
        background,
        antialiased,
        ..Default::default()
    };
    let (pixels, isects) = py
        .detach(|| with_renderer(|r| r.forward(&input, &camera, &settings)))
        .map_err(to_py)?;
    Ok((PyArray1::from_vec(py, pixels), isects))
}

/// Gradients w.r.t. (means, log_scales, quats, opacity_logits, sh), flat float32, given
/// the gradient of the loss w.r.t. render_forward's output (same layout).
#[pyfunction]
#[pyo3(signature = (means, log_scales, quats, opacity_logits, sh, k, world_to_cam, half_fov_tan, width, height, background, antialiased, v_pixels))]
#[allow(clippy::too_many_arguments)]
fn render_backward<'py>(
    py: Python<'py>,
    means: PyReadonlyArray1<'py, f32>,
    log_scales: PyReadonlyArray1<'py, f32>,
    quats: PyReadonlyArray1<'py, f32>,
    opacity_logits: PyReadonlyArray1<'py, f32>,
    sh: PyReadonlyArray1<'py, f32>,
    k: PyReadonlyArray2<'py, f64>,
    world_to_cam: PyReadonlyArray2<'py, f64>,
    half_fov_tan: [f64; 2],
    width: u32,
    height: u32,
    background: [f32; 3],
    antialiased: bool,
    v_pixels: PyReadonlyArray1<'py, f32>,
) -> PyResult<Bound<'py, PyDict>> {
    let camera = camera_from(&k, &world_to_cam, half_fov_tan, width, height)?;
    let input = scene(&means, &log_scales, &quats, &opacity_logits, &sh)?;
    let v = slice("v_pixels", &v_pixels)?;
    let settings = RenderSettings {
        background,
        antialiased,
        ..Default::default()
    };
    let grads = py
        .detach(|| with_renderer(|r| r.backward(&input, &camera, &settings, v)))
        .map_err(to_py)?;
    let out = PyDict::new(py);
    out.set_item("means", PyArray1::from_vec(py, grads.means))?;
    out.set_item("log_scales", PyArray1::from_vec(py, grads.log_scales))?;
    out.set_item("quats", PyArray1::from_vec(py, grads.quats))?;
    out.set_item(
        "opacity_logits",
        PyArray1::from_vec(py, grads.opacity_logits),
    )?;
    out.set_item("sh", PyArray1::from_vec(py, grads.sh))?;
    Ok(out)
}

/// Each Gaussian's footprint as the projection computes it for the blending (N*3 float32:
/// pixel centre x, y and radius; radius 0 where it is culled).
#[pyfunction]
#[pyo3(signature = (means, log_scales, quats, opacity_logits, sh, k, world_to_cam, half_fov_tan, width, height, antialiased))]
#[allow(clippy::too_many_arguments)]
fn footprints<'py>(
    py: Python<'py>,
    means: PyReadonlyArray1<'py, f32>,
    log_scales: PyReadonlyArray1<'py, f32>,
    quats: PyReadonlyArray1<'py, f32>,
    opacity_logits: PyReadonlyArray1<'py, f32>,
    sh: PyReadonlyArray1<'py, f32>,
    k: PyReadonlyArray2<'py, f64>,
    world_to_cam: PyReadonlyArray2<'py, f64>,
    half_fov_tan: [f64; 2],
    width: u32,
    height: u32,
    antialiased: bool,
) -> PyResult<Bound<'py, PyArray1<f32>>> {
    let camera = camera_from(&k, &world_to_cam, half_fov_tan, width, height)?;
    let input = scene(&means, &log_scales, &quats, &opacity_logits, &sh)?;
    let settings = RenderSettings {
        antialiased,
        ..Default::default()
    };
    let footprints = py
        .detach(|| with_renderer(|r| r.footprints(&input, &camera, &settings)))
        .map_err(to_py)?;
    Ok(PyArray1::from_vec(py, footprints.concat()))
}

/// The adapter the renderer uses: {name, backend, device_type, driver} and which of the
/// backward's paths it takes: {subgroups, float_atomics} ("yes" or "no").
#[pyfunction]
fn adapter_info(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let (summary, subgroups, float_atomics) = py
        .detach(|| {
            with_renderer(|r| {
                let ctx = r.context();
                Ok((
                    ctx.adapter.clone(),
                    ctx.has_subgroups(),
                    ctx.has_float_atomics(),
                ))
            })
        })
        .map_err(to_py)?;
    let yes_no = |on: bool| if on { "yes" } else { "no" };
    let out = PyDict::new(py);
    out.set_item("name", summary.name)?;
    out.set_item("backend", summary.backend)?;
    out.set_item("device_type", summary.device_type)?;
    out.set_item("driver", summary.driver)?;
    out.set_item("subgroups", yes_no(subgroups))?;
    out.set_item("float_atomics", yes_no(float_atomics))?;
    Ok(out)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(render_forward, m)?)?;
    m.add_function(wrap_pyfunction!(render_backward, m)?)?;
    m.add_function(wrap_pyfunction!(footprints, m)?)?;
    m.add_function(wrap_pyfunction!(adapter_info, m)?)?;
    Ok(())
}
