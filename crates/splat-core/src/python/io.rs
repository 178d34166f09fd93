//! `.ply` and `.ply4d` I/O for Python (`pano4d.ply4d` wraps these).
//!
//! Gaussian sets cross as dicts of C-contiguous float32 arrays with the keys of
//! `Gaussians.to_numpy()`: means (N, 3), log_scales (N, 3), quats (N, 4),
//! opacity_logits (N,), sh (N, K, 3). Format errors raise ValueError, OS errors OSError.

use std::path::PathBuf;

use numpy::prelude::*;
use numpy::{PyArray1, PyReadonlyArrayDyn};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::gaussians::{sh_coeffs, GaussianSet};
use crate::ply::{self, FileError};
use crate::ply4d::{Ply4dReader, Ply4dWriter, SceneMeta};

fn to_py_err(e: FileError) -> PyErr {
    match e {
        FileError::Io { .. } => PyOSError::new_err(e.to_string()),
        FileError::Invalid(msg) => PyValueError::new_err(msg),
    }
}

fn set_to_dict(py: Python<'_>, set: GaussianSet) -> PyResult<Bound<'_, PyDict>> {
    let n = set.len();
    let k = sh_coeffs(set.sh_degree);
    let dict = PyDict::new(py);
    let means: Vec<f32> = set.means.into_iter().flatten().collect();
    let log_scales: Vec<f32> = set.log_scales.into_iter().flatten().collect();
    let quats: Vec<f32> = set.quats.into_iter().flatten().collect();
    dict.set_item("means", PyArray1::from_vec(py, means).reshape([n, 3])?)?;
    dict.set_item(
        "log_scales",
        PyArray1::from_vec(py, log_scales).reshape([n, 3])?,
    )?;
    dict.set_item("quats", PyArray1::from_vec(py, quats).reshape([n, 4])?)?;
    dict.set_item("opacity_logits", PyArray1::from_vec(py, set.opacity_logits))?;
    dict.set_item("sh", PyArray1::from_vec(py, set.sh).reshape([n, k, 3])?)?;
    Ok(dict)
}

/// One array of the dict, flattened, checked against `shape` (None = any), with its shape.
fn array_values(
    arrays: &Bound<'_, PyDict>,
    key: &str,
    shape: &[Option<usize>],
) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let Some(value) = arrays.get_item(key)? else {
        return Err(PyValueError::new_err(format!(
            "Gaussian arrays lack '{key}'"
        )));
    };
    let array: PyReadonlyArrayDyn<'_, f32> = value
        .extract()
        .map_err(|_| PyValueError::new_err(format!("'{key}' must be a float32 numpy array")))?;
    let got = array.shape();
    let matches = got.len() == shape.len()
        && got
            .iter()
            .zip(shape)
            .all(|(g, w)| w.is_none_or(|w| w == *g));
    if !matches {
        return Err(PyValueError::new_err(format!(
            "'{key}' has shape {got:?}, expected {shape:?} (None = any)"
        )));
    }
    let slice = array
        .as_slice()
        .map_err(|_| PyValueError::new_err(format!("'{key}' must be C-contiguous")))?;
    Ok((got.to_vec(), slice.to_vec()))
}

fn set_from_dict(arrays: &Bound<'_, PyDict>) -> PyResult<GaussianSet> {
    let (means_shape, means) = array_values(arrays, "means", &[None, Some(3)])?;
    let n = means_shape[0];
    let (sh_shape, sh) = array_values(arrays, "sh", &[Some(n), None, Some(3)])?;
    let k = sh_shape[1];
    let Some(sh_degree) = (0..=3).find(|&d| sh_coeffs(d) == k) else {
        return Err(PyValueError::new_err(format!(
            "'sh' has {k} coefficients per channel, not (degree + 1)^2 for degree 0..3"
        )));
    };
    let triples = |v: Vec<f32>| {
        v.chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect::<Vec<_>>()
    };
    let (_, quats) = array_values(arrays, "quats", &[Some(n), Some(4)])?;
    let (_, log_scales) = array_values(arrays, "log_scales", &[Some(n), Some(3)])?;
    let (_, opacity_logits) = array_values(arrays, "opacity_logits", &[Some(n)])?;
    Ok(GaussianSet {
        sh_degree,
        means: triples(means),
        log_scales: triples(log_scales),
        quats: quats
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
        opacity_logits,
        sh,
    })
}

/// Reads a standard or SuperSplat-compressed 3DGS `.ply` into a dict of arrays.
#[pyfunction]
fn read_ply(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    let set = py.detach(|| ply::read_ply(&path)).map_err(to_py_err)?;
    set_to_dict(py, set)
}

/// Writes a dict of arrays as a standard 3DGS `.ply`, atomically.
#[pyfunction]
fn write_ply(py: Python<'_>, path: PathBuf, arrays: &Bound<'_, PyDict>) -> PyResult<()> {
    let set = set_from_dict(arrays)?;
    py.detach(|| ply::write_ply(&path, &set)).map_err(to_py_err)
}

/// Streams a `.ply4d`: the static set first, then one dynamic set per `push`, then
/// `finish(meta_json)` with timestamps, fps, camera, provenance and extra as JSON.
/// A writer closed or dropped before `finish` leaves no file behind.
#[pyclass(name = "Ply4dWriter", module = "pano4d._core")]
struct PyPly4dWriter {
    inner: Option<Ply4dWriter>,
}

fn closed_writer() -> PyErr {
    PyValueError::new_err("the .ply4d writer is already finished or closed")
}

impl PyPly4dWriter {
    fn writer(&mut self) -> PyResult<&mut Ply4dWriter> {
        self.inner.as_mut().ok_or_else(closed_writer)
    }
}

#[pymethods]
impl PyPly4dWriter {
    #[new]
    fn create(py: Python<'_>, path: PathBuf, static_set: &Bound<'_, PyDict>) -> PyResult<Self> {
        let set = set_from_dict(static_set)?;
        let inner = py
            .detach(|| Ply4dWriter::create(&path, &set))
            .map_err(to_py_err)?;
        Ok(Self { inner: Some(inner) })
    }

    fn push(&mut self, py: Python<'_>, arrays: &Bound<'_, PyDict>) -> PyResult<()> {
        let set = set_from_dict(arrays)?;
        let writer = self.writer()?;
        py.detach(|| writer.push(&set)).map_err(to_py_err)
    }

    fn finish(&mut self, py: Python<'_>, meta_json: &str) -> PyResult<()> {
        let meta: SceneMeta = serde_json::from_str(meta_json)
            .map_err(|e| PyValueError::new_err(format!("invalid .ply4d scene metadata: {e}")))?;
        let writer = self.inner.take().ok_or_else(closed_writer)?;
        py.detach(|| writer.finish(meta)).map_err(to_py_err)
    }

    /// Abandons an unfinished writer (its scratch data is deleted); no-op once finished.
    fn close(&mut self) {
        self.inner = None;
    }
}

/// An open, memory-mapped `.ply4d` file; sections are decoded on request.
#[pyclass(frozen, name = "Ply4dReader", module = "pano4d._core")]
struct PyPly4dReader {
    inner: Ply4dReader,
}

#[pymethods]
impl PyPly4dReader {
    #[new]
    fn open(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let inner = py.detach(|| Ply4dReader::open(&path)).map_err(to_py_err)?;
        Ok(Self { inner })
    }

    /// The JSON header, as text.
    fn header_json(&self) -> PyResult<String> {
        serde_json::to_string(self.inner.header()).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    #[getter]
    fn num_times(&self) -> usize {
        self.inner.num_times()
    }

    fn read_static<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let set = py.detach(|| self.inner.read_static()).map_err(to_py_err)?;
        set_to_dict(py, set)
    }

    fn read_dynamic<'py>(&self, py: Python<'py>, t: usize) -> PyResult<Bound<'py, PyDict>> {
        let set = py
            .detach(|| self.inner.read_dynamic(t))
            .map_err(to_py_err)?;
        set_to_dict(py, set)
    }

    fn read_at<'py>(&self, py: Python<'py>, t: usize) -> PyResult<Bound<'py, PyDict>> {
        let set = py.detach(|| self.inner.read_at(t)).map_err(to_py_err)?;
        set_to_dict(py, set)
    }

    /// Checks every section's CRC32.
    fn verify(&self, py: Python<'_>) -> PyResult<()> {
        py.detach(|| self.inner.verify()).map_err(to_py_err)
    }

    /// Writes timestamp `t` (static + dynamic) as a plain `.ply`, atomically.
    fn export_ply(&self, py: Python<'_>, t: usize, path: PathBuf) -> PyResult<()> {
        py.detach(|| self.inner.export_ply(t, &path))
            .map_err(to_py_err)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_ply, m)?)?;
    m.add_function(wrap_pyfunction!(write_ply, m)?)?;
    m.add_class::<PyPly4dReader>()?;
    m.add_class::<PyPly4dWriter>()?;
    Ok(())
}
