//! Python bindings of the rasteriser: the camera a render is seen by (`View`),
//! `render_forward` (a `RasterOutput`), `render_backward` (gradients as `GaussianArrays`),
//! `footprints`,
//! `adapter_info`.
//!
//! One process-wide [`Renderer`] (device, pipelines, buffers) is created on first use
//! and reused; calls are serialised by a mutex and run with the GIL released.

use std::sync::{Mutex, OnceLock};

use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::gaussians::PyGaussianArrays;
use crate::camera::Camera;
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

/// A pinhole camera as the renderer takes it (`pano4d.camera.Camera`'s K, world-to-camera
/// rows, the tan of its view's half field of view and its size in pixels), built by keyword
/// by `pano4d.extension.view`.
#[pyclass(name = "View", module = "pano4d._core", frozen)]
pub struct PyView {
    pub(super) camera: Camera,
}

#[pymethods]
impl PyView {
    /// `k`: 3×3 intrinsics; `world_to_cam`: 3×4 or 4×4 rows, float64; `half_fov_tan`: the
    /// (x, y) tan of the half field of view of the whole view (a window keeps its view's).
    #[new]
    #[pyo3(signature = (*, k, world_to_cam, half_fov_tan, width, height))]
    fn new(
        k: PyReadonlyArray2<'_, f64>,
        world_to_cam: PyReadonlyArray2<'_, f64>,
        half_fov_tan: [f64; 2],
        width: u32,
        height: u32,
    ) -> PyResult<Self> {
        let k = k.as_array();
        let w2c = world_to_cam.as_array();
        if k.shape() != [3, 3] || w2c.shape()[1] != 4 || !(3..=4).contains(&w2c.shape()[0]) {
            return Err(PyValueError::new_err(
                "K must be 3x3 and world_to_cam 3x4 or 4x4",
            ));
        }
        let kk = std::array::from_fn(|r| std::array::from_fn(|c| k[[r, c]]));
        let ww = std::array::from_fn(|r| std::array::from_fn(|c| w2c[[r, c]]));
        let camera = Camera {
            half_fov_tan: half_fov_tan.into(),
            ..Camera::from_matrices(kk, ww, width, height)
        };
        Ok(Self { camera })
    }

    #[getter]
    fn width(&self) -> u32 {
        self.camera.width
    }

    #[getter]
    fn height(&self) -> u32 {
        self.camera.height
    }

    fn __repr__(&self) -> String {
        format!("View(<{}x{}>)", self.camera.width, self.camera.height)
    }
}

pub(super) fn slice<'a>(name: &str, a: &'a PyReadonlyArray1<'_, f32>) -> PyResult<&'a [f32]> {
    a.as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name} must be a C-contiguous float32 array")))
}

/// A frame rendered by [`render_forward`].
#[pyclass(name = "RasterOutput", module = "pano4d._core", frozen)]
pub struct PyRasterOutput {
    pixels: Py<PyArray1<f32>>,
    intersections: u32,
}

#[pymethods]
impl PyRasterOutput {
    /// H·W·5 float32: r, g, b, alpha, Σ z·α·T per pixel.
    #[getter]
    fn pixels(&self, py: Python<'_>) -> Py<PyArray1<f32>> {
        self.pixels.clone_ref(py)
    }

    /// The frame's (Gaussian, tile) intersections.
    #[getter]
    fn intersections(&self) -> u32 {
        self.intersections
    }
}

/// The settings Python's renders and training sessions draw with: a background and a mode
/// (the viewer's splat scale stays at 1).
pub(super) fn render_settings(background: [f32; 3], antialiased: bool) -> RenderSettings {
    RenderSettings {
        background,
        antialiased,
        ..Default::default()
    }
}

/// Renders `gaussians` seen by `view`.
#[pyfunction]
#[pyo3(signature = (gaussians, view, *, background, antialiased))]
fn render_forward(
    py: Python<'_>,
    gaussians: PyRef<'_, PyGaussianArrays>,
    view: PyRef<'_, PyView>,
    background: [f32; 3],
    antialiased: bool,
) -> PyResult<PyRasterOutput> {
    let (input, camera) = (gaussians.input(), view.camera);
    let settings = render_settings(background, antialiased);
    let (pixels, intersections) = py
        .detach(|| with_renderer(|r| r.forward(&input, &camera, &settings)))
        .map_err(to_py)?;
    Ok(PyRasterOutput {
        pixels: PyArray1::from_vec(py, pixels).unbind(),
        intersections,
    })
}

/// The gradients of a loss w.r.t. each array of `gaussians` (in their shapes), given its
/// gradient w.r.t. render_forward's pixels (`v_pixels`, H·W·5).
#[pyfunction]
#[pyo3(signature = (gaussians, view, *, background, antialiased, v_pixels))]
fn render_backward(
    py: Python<'_>,
    gaussians: PyRef<'_, PyGaussianArrays>,
    view: PyRef<'_, PyView>,
    background: [f32; 3],
    antialiased: bool,
    v_pixels: PyReadonlyArray1<'_, f32>,
) -> PyResult<PyGaussianArrays> {
    let (input, camera) = (gaussians.input(), view.camera);
    let v = slice("v_pixels", &v_pixels)?;
    let settings = render_settings(background, antialiased);
    let grads = py
        .detach(|| with_renderer(|r| r.backward(&input, &camera, &settings, v)))
        .map_err(to_py)?;
    let packed = [
        grads.means,
        grads.log_scales,
        grads.quats,
        grads.opacity_logits,
        grads.sh,
    ]
    .concat();
    let set = gaussians.set();
    Ok(PyGaussianArrays::from_packed(
        &packed,
        set.len(),
        set.sh_degree,
    ))
}

/// Each Gaussian's footprint as the projection computes it for the blending (N*3 float32:
/// pixel centre x, y and radius; radius 0 where it is culled).
#[pyfunction]
#[pyo3(signature = (gaussians, view, *, antialiased))]
fn footprints<'py>(
    py: Python<'py>,
    gaussians: PyRef<'py, PyGaussianArrays>,
    view: PyRef<'py, PyView>,
    antialiased: bool,
) -> PyResult<Bound<'py, PyArray1<f32>>> {
    let (input, camera) = (gaussians.input(), view.camera);
    let settings = render_settings([0.0; 3], antialiased);
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
    m.add_class::<PyView>()?;
    m.add_class::<PyRasterOutput>()?;
    m.add_function(wrap_pyfunction!(render_forward, m)?)?;
    m.add_function(wrap_pyfunction!(render_backward, m)?)?;
    m.add_function(wrap_pyfunction!(footprints, m)?)?;
    m.add_function(wrap_pyfunction!(adapter_info, m)?)?;
    Ok(())
}
